"""Backwards-compatible import path (a re-export): the throw's outcome lives in
:mod:`besdrake.tasks.throwing.outcome`; each task defines its own outcome."""

from besdrake.tasks.throwing.outcome import FLAG_NAMES, Outcome

__all__ = ["FLAG_NAMES", "Outcome"]
