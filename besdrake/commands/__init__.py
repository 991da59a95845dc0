"""Subcommands of the ``besdrake`` CLI, one module each (see :mod:`besdrake.cli`)."""
