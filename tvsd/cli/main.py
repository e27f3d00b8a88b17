# PYTHON_ARGCOMPLETE_OK  (argcomplete looks for this marker in the entry point's module)
"""tvsctl — the command line of tvsd.

Subcommands live in one module each, listed in COMMANDS (one line per command, like python-can's
BACKENDS table). Each module offers ``register(subparsers)`` and sets ``func`` on its parser; the
function returns an exit status. Errors derived from TvsdError become one line on stderr and their
documented exit status; anything else is a bug and says so.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import select
import sys
from collections.abc import Sequence
from typing import Any

from tvsd import __version__
from tvsd.errors import EXIT_INTERNAL, EXIT_PIPE, EXIT_USAGE, TvsdError

_DAEMON_COMMANDS = (
    "status",
    "speed",
    "scan",
    "aim",
    "gains",
    "record",
    "faults",
    "points",
    "calibrate-imu",
    "shutdown",
)

# command name -> module offering register(subparsers) (a module may register several commands).
# Only the invoked command's module is imported: the others pull in scipy, python-can, numba
# kernels, and would cost every call a second of start-up.
COMMANDS: dict[str, str] = {
    "sim": "tvsd.cli.sim",
    "bench": "tvsd.cli.bench",
    "analyze": "tvsd.cli.analyze",
    "imu": "tvsd.cli.imu",
    "mcu": "tvsd.cli.mcu",
    "export": "tvsd.cli.export",
    "latency": "tvsd.cli.latency",
    "watch": "tvsd.cli.watch",
    "identify": "tvsd.cli.identify",  # a thin client of tvsd's socket too, with its own progress
    **dict.fromkeys(_DAEMON_COMMANDS, "tvsd.cli.daemon_cmds"),  # thin clients of tvsd's socket
}


# argparse takes `-1e3` for an option (its own pattern knows -1 and -.5 only) and refuses
# `--start -1e3` with "expected one argument": this one knows a negative number in any float form.
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


class _Parser(argparse.ArgumentParser):
    """argparse that exits with EXIT_USAGE and a one-line hint, as every bad input should."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def build_parser(argv: Sequence[str] = ()) -> argparse.ArgumentParser:
    """The parser for this call: the invoked command's module only, or every module (help, a
    typo, no command) so that argparse can list and suggest them all."""
    parser = _Parser(prog="tvsctl", description="Command line of the TVS scanner daemon tvsd.")
    parser.add_argument("--version", action="version", version=f"tvsctl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    command = next((a for a in argv if not a.startswith("-")), None)
    modules = [COMMANDS[command]] if command in COMMANDS else list(dict.fromkeys(COMMANDS.values()))
    for module_name in modules:
        importlib.import_module(module_name).register(sub)
    return parser


def _complete() -> None:
    """Shell completion (argcomplete): answers and exits when the shell asks, else returns at once.
    Only the typed command's module is loaded, as for a run; the command list needs them all."""
    if "_ARGCOMPLETE" not in os.environ:
        return
    import argcomplete

    words = os.environ.get("COMP_LINE", "")[: int(os.environ.get("COMP_POINT", "0") or 0)].split()[1:]
    typed = words if len(words) > 1 or os.environ.get("COMP_LINE", "").endswith(" ") else []
    argcomplete.autocomplete(build_parser(typed))


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command. When stdout's reader goes away (`tvsctl faults | head`) the command stops
    quietly with EXIT_PIPE: stdout is flushed inside the try (a buffered line would otherwise fail
    at the interpreter's exit, "Exception ignored … BrokenPipeError") and then pointed at
    /dev/null, the Python docs' recipe (library/signal.html, "Note on SIGPIPE")."""
    try:
        try:
            status = _main(argv)
        finally:  # also after argparse's --help / usage error, which leave by SystemExit
            sys.stdout.flush()
    except BrokenPipeError:
        if not _stdout_gone():
            raise  # another pipe (a socket): not the reader of stdout going away
        return _quiet_stdout()
    except SystemExit as exc:  # argparse's --help/--version swallow the failed write and exit 0
        if exc.code in (0, None) and _stdout_gone():
            return _quiet_stdout()
        raise
    return status


def _quiet_stdout() -> int:
    """Point fd 1 at /dev/null (the interpreter's last flush must not fail) and say EXIT_PIPE."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return EXIT_PIPE


def _stdout_gone() -> bool:
    """Whether fd 1 is a pipe whose reader has closed it: Linux's poll() says POLLERR for it."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, ValueError):  # stdout closed or replaced by an object without a descriptor
        return False


def _main(argv: Sequence[str] | None) -> int:
    if argv is None:
        _complete()
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    try:
        status: int = args.func(args)
        sys.stdout.flush()  # a write that fails here is still the command's, handled below
    except TvsdError as exc:
        print(f"tvsctl: {exc}", file=sys.stderr)
        return exc.exit_status
    except KeyboardInterrupt:
        print("tvsctl: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        if _stdout_gone():
            raise  # main() makes it quiet
        print(
            "tvsctl: internal error (BrokenPipeError: a pipe other than stdout closed); please report it",
            file=sys.stderr,
        )
        return EXIT_INTERNAL
    except Exception as exc:  # a bug: say so plainly, with enough to report it
        print(f"tvsctl: internal error ({type(exc).__name__}: {exc}); please report it", file=sys.stderr)
        if "--debug" in sys.argv:
            raise
        return EXIT_INTERNAL
    return status


if __name__ == "__main__":
    sys.exit(main())
