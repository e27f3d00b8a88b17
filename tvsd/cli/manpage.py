"""Man pages generated from the argparse parsers (`make man`, or `python -m tvsd.cli.manpage DIR`).

tvsctl.1 walks tvsctl's whole parser tree (every command and subcommand with its options, as
`--help` shows them), tvsd.1 the daemon's parser; both add the exit statuses and the environment.
Generated, never edited: a new option appears in the page by being added to its parser.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from collections.abc import Iterator
from pathlib import Path

from tvsd import __version__

EXIT_STATUSES = (
    ("0", "done"),
    ("1", "the command ran, the result is a failure"),
    ("2", "bad input: arguments, config, data file (one line on stderr: what, where, the fix)"),
    ("3", "a device or the daemon is unreachable"),
    ("70", "a bug in tvsd (please report it with the line printed)"),
    ("130", "interrupted (Ctrl-C); bench prints the groups done"),
)


def esc(text: str) -> str:
    """Text for roff: backslashes, hyphens in options, and a leading dot or quote neutralised."""
    out = text.replace("\\", "\\e").replace("-", "\\-")
    return "\n".join("\\&" + line if line[:1] in (".", "'") else line for line in out.split("\n"))


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    formatter = parser._get_formatter()
    return formatter._expand_help(action) if action.help else ""


def _subparsers(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser, str]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield name, sub, helps.get(name, "")


def _options(parser: argparse.ArgumentParser) -> list[str]:
    lines: list[str] = []
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        formatter = parser._get_formatter()
        if action.option_strings:
            spec = formatter._format_action_invocation(action)
        else:
            spec = formatter._metavar_formatter(action, action.dest)(1)[0]
        lines += [".TP", f"\\fB{esc(spec)}\\fR", esc(_help(parser, action)) or "\\&"]
    return lines


def _usage(parser: argparse.ArgumentParser) -> str:
    return " ".join(parser.format_usage().removeprefix("usage: ").split())


def command_sections(parser: argparse.ArgumentParser, path: str) -> list[str]:
    """.SS per command, depth first: usage, description, options."""
    out: list[str] = []
    for name, sub, help_ in _subparsers(parser):
        full = f"{path} {name}"
        out += [f'.SS "{esc(full)}"', esc(help_), ".PP", f"\\fB{esc(_usage(sub))}\\fR"]
        if sub.description and sub.description != help_:
            out += [".PP", esc(sub.description)]
        opts = _options(sub)
        if opts:
            out += [".RS", *opts, ".RE"]
        out += command_sections(sub, full)
    return out


def page(parser: argparse.ArgumentParser, name: str, summary: str, extra: list[str]) -> str:
    date = dt.date.today().isoformat()
    lines = [
        f'.TH {name.upper()} 1 "{date}" "tvsd {__version__}" "TVS scanner"',
        ".SH NAME",
        f"{name} \\- {esc(summary)}",
        ".SH SYNOPSIS",
        f"\\fB{esc(_usage(parser))}\\fR",
        ".SH DESCRIPTION",
        esc(parser.description or summary),
        ".SH OPTIONS",
        *_options(parser),
    ]
    commands = command_sections(parser, name)
    if commands:
        lines += [".SH COMMANDS", *commands]
    lines += [".SH EXIT STATUS"]
    for code, meaning in EXIT_STATUSES:
        lines += [".TP", f"\\fB{code}\\fR", esc(meaning)]
    lines += extra
    see = "README.md and docs/architecture.md of tvsd; \\fBtvsd\\fR(1), \\fBtvsctl\\fR(1)"
    lines += [".SH SEE ALSO", see]
    return "\n".join(lines) + "\n"


class _Captured(Exception):
    def __init__(self, parser: argparse.ArgumentParser) -> None:
        self.parser = parser


def daemon_parser() -> argparse.ArgumentParser:
    """tvsd's parser as its main module builds it (captured at parse time, nothing is run)."""
    from tvsd.daemon import main as daemon_main

    original = argparse.ArgumentParser.parse_args

    def capture(self: argparse.ArgumentParser, *args: object, **kw: object) -> argparse.Namespace:
        raise _Captured(self)

    argparse.ArgumentParser.parse_args = capture  # type: ignore[assignment,method-assign]
    try:
        daemon_main.parse([])
    except _Captured as got:
        return got.parser
    finally:
        argparse.ArgumentParser.parse_args = original  # type: ignore[method-assign]
    raise RuntimeError("tvsd.daemon.main.parse did not build a parser")


ENVIRONMENT = [
    ".SH ENVIRONMENT",
    ".TP",
    "\\fBTVSD_SOCKET\\fR",
    "the daemon's socket when \\fB\\-\\-socket\\fR is not given (else /run/tvsd/tvsd.sock)",
    ".SH COMPLETION",
    "bash: \\fBeval \"$(register\\-python\\-argcomplete tvsctl)\"\\fR in ~/.bashrc "
    "(zsh: the same after \\fBautoload \\-U bashcompinit; bashcompinit\\fR; fish: "
    "\\fBregister\\-python\\-argcomplete \\-\\-shell fish tvsctl | source\\fR).",
]


def write_pages(directory: Path) -> list[Path]:
    from tvsd.cli.main import build_parser

    directory.mkdir(parents=True, exist_ok=True)
    pages = {
        "tvsctl": page(build_parser([]), "tvsctl", "command line of the TVS scanner daemon", ENVIRONMENT),
        "tvsd": page(daemon_parser(), "tvsd", "controller daemon of the TVS laser scanner", []),
    }
    out = []
    for name, text in pages.items():
        path = directory / f"{name}.1"
        path.write_text(text)
        out.append(path)
    return out


if __name__ == "__main__":
    for p in write_pages(Path(sys.argv[1] if len(sys.argv) > 1 else "man")):
        print(p)
