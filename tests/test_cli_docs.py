"""Man pages generated from the parsers, and shell completion (argcomplete), issue 15 item 4."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tvsd.cli.main import COMMANDS, build_parser
from tvsd.cli.manpage import write_pages


def _walk(parser, path=("tvsctl",)):  # type: ignore[no-untyped-def]
    yield path, parser
    for action in parser._actions:
        if action.__class__.__name__ == "_SubParsersAction":
            for name, sub in action.choices.items():
                yield from _walk(sub, (*path, name))


def test_man_pages_hold_every_command_and_option(tmp_path: Path) -> None:
    tvsctl, tvsd = write_pages(tmp_path)
    text = tvsctl.read_text()
    for path, parser in _walk(build_parser([])):
        if len(path) > 1:
            assert f'.SS "{" ".join(path)}"'.replace("-", "\\-") in text, path
        for action in parser._actions:
            for opt in action.option_strings:
                if opt not in ("-h", "--help"):
                    assert opt.replace("-", "\\-") in text, (path, opt)
    assert all(f'.SS "tvsctl {c}"'.replace("-", "\\-") in text for c in COMMANDS)
    daemon = tvsd.read_text()
    assert all(o in daemon for o in ("\\-\\-sil", "\\-\\-socket", "\\-\\-realtime", "\\-\\-check"))


@pytest.mark.skipif(shutil.which("groff") is None, reason="groff is not installed (apt-get install groff)")
def test_man_pages_render_without_warnings(tmp_path: Path) -> None:
    for page in write_pages(tmp_path):
        proc = subprocess.run(["groff", "-k", "-man", "-ww", "-z", str(page)], capture_output=True, text=True)
        assert proc.returncode == 0 and proc.stderr == "", proc.stderr


COMPLETIONS = [
    ("tvsctl wa", {"watch"}),
    ("tvsctl sim sp", {"spin"}),
    ("tvsctl sim spin --rp", {"--rps"}),
    ("tvsctl export rec --format ", {"csv", "parquet", "mcap"}),
    ("tvsctl points --ti", {"--timeout"}),
]


def _completion_env(line: str, out: Path) -> dict[str, str]:
    return {"_ARGCOMPLETE": "1", "COMP_LINE": line, "COMP_POINT": str(len(line)),
            "_ARGCOMPLETE_STDOUT_FILENAME": str(out)}  # fmt: skip


def _read(out: Path) -> set[str]:
    return {w.strip() for w in out.read_text().split("\x0b")}


@pytest.mark.parametrize(("line", "expect"), COMPLETIONS)
def test_shell_completion(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, line: str, expect: set[str]
) -> None:
    """What bash gets through argcomplete, in this process (argcomplete exits: caught)."""
    import argcomplete

    from tvsd.cli import main

    out = tmp_path / "completions"
    for k, v in _completion_env(line, out).items():
        monkeypatch.setenv(k, v)
    real = argcomplete.autocomplete
    monkeypatch.setattr(argcomplete, "autocomplete", lambda p: real(p, exit_method=sys.exit))
    # argcomplete writes its debug to fd 9, which in pytest is faulthandler's: keep off it
    monkeypatch.setattr(
        argcomplete.finders.CompletionFinder,
        "_init_debug_stream",
        lambda self: setattr(argcomplete.io, "debug_stream", sys.stderr),
    )
    with pytest.raises(SystemExit) as info:
        main.main()
    assert info.value.code == 0
    assert _read(out) == expect


def test_shell_completion_through_the_installed_command(tmp_path: Path) -> None:
    """The real path once: the tvsctl script, argcomplete finding the marker, its exit."""
    out = tmp_path / "completions"
    tvsctl = Path(sys.executable).with_name("tvsctl")
    env = {**os.environ, **_completion_env("tvsctl sim sp", out)}
    proc = subprocess.run([str(tvsctl)], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and _read(out) == {"spin"}, proc.stderr


def test_the_entry_point_module_carries_the_argcomplete_marker() -> None:
    import tvsd.cli.main as m

    assert "PYTHON_ARGCOMPLETE_OK" in Path(m.__file__).read_text()[:1024]
