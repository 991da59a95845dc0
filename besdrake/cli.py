"""The ``besdrake`` command line.

Each stage adds its subcommands as a module in :mod:`besdrake.commands` that defines

* ``COMMAND``: the command path, e.g. ``("simulate",)`` or ``("bench", "rollout")``;
* ``HELP``: one line of help;
* ``add_arguments(parser)``: fills an :class:`argparse.ArgumentParser`;
* ``run(args) -> int``: does the work and returns the exit status.

Modules are discovered, so a stage never edits this file to add a command.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
import tempfile
import time
import traceback
from types import ModuleType

from besdrake import __version__


class UserError(Exception):
    """An error caused by the user's input: printed without a traceback, exit status 2."""


def _command_modules() -> list[ModuleType]:
    import besdrake.commands as pkg

    modules = []
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{pkg.__name__}.{info.name}")
        if hasattr(module, "COMMAND"):
            modules.append(module)
    return modules


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="besdrake", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"besdrake {__version__}")
    root = parser.add_subparsers(dest="command", metavar="COMMAND")
    groups: dict[tuple[str, ...], argparse._SubParsersAction] = {(): root}
    for module in _command_modules():
        path = tuple(module.COMMAND)
        for depth in range(1, len(path)):
            prefix = path[:depth]
            if prefix not in groups:
                group_parser = groups[prefix[:-1]].add_parser(prefix[-1], help=f"{prefix[-1]} commands")
                groups[prefix] = group_parser.add_subparsers(dest=f"command_{depth}", metavar="COMMAND")
        sub = groups[path[:-1]].add_parser(path[-1], help=module.HELP, description=module.HELP)
        module.add_arguments(sub)
        sub.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    run = getattr(args, "_run", None)
    if run is None:
        parser.print_help()
        return 2
    from besdrake._io import OutputError

    try:
        return int(run(args) or 0)
    except (UserError, OutputError) as err:
        print(f"besdrake: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("besdrake: interrupted; the run folder can be resumed", file=sys.stderr)
        return 130
    except SystemExit as err:  # raised by user code (a plugin), never by a command: it must not end a run silently
        print(f"besdrake: error: the run was stopped by sys.exit({err.code!r}) in user code (a plugin?); "
              "a plugin must raise an exception instead", file=sys.stderr)
        return 2
    except Exception as err:  # noqa: BLE001 - last resort: a bug, reported with its traceback in a file
        if os.environ.get("BESDRAKE_DEBUG"):
            raise
        return _internal_error(err)


def _internal_error(err: Exception) -> int:
    """Print one ``besdrake: error: internal error`` line and write the traceback to a file (exit 2)."""
    text = "".join(traceback.format_exception(type(err), err, err.__traceback__))
    fd, path = tempfile.mkstemp(prefix=f"besdrake-crash-{time.strftime('%Y%m%d-%H%M%S')}-", suffix=".txt")
    with os.fdopen(fd, "w") as f:
        f.write(f"besdrake {__version__}\nargv: {sys.argv!r}\n\n{text}")
    print(f"besdrake: error: internal error ({type(err).__name__}: {err}); traceback in {path} "
          "(please report; BESDRAKE_DEBUG=1 shows it here)", file=sys.stderr)
    return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
