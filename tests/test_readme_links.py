"""The README and docs/ as a stranger reads them: every relative link resolves (file, and heading
anchor where one is given), and every `tvsctl …` / `tvsd …` line of the README's `sh` blocks is
accepted by the real argument parsers (nothing runs: argparse only, no daemon; the links take < 1 s,
the parsers' imports 10-15 s on an idle 2-core machine, so those are marked slow)."""

from __future__ import annotations

import re
import shlex
import unicodedata
from pathlib import Path

import pytest

from tvsd.cli.main import build_parser
from tvsd.daemon.main import parse as parse_tvsd

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted(ROOT.glob("docs/**/*.md"))
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)


def _prose(text: str) -> str:
    """The text outside fenced blocks and inline code, where a link is a link."""
    text = FENCE.sub("", text)
    return re.sub(r"`[^`\n]*`", "", text)


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip()).lower()
    kept = "".join(c for c in text if c in " -" or unicodedata.category(c)[0] in "LN")
    return kept.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = FENCE.sub("", path.read_text())
    seen: dict[str, int] = {}
    out = set()
    for heading in re.findall(r"^#{1,6} (.+)$", text, re.M):
        slug = _slug(heading)
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def _links(path: Path) -> list[str]:
    return [a or b for a, b in LINK.findall(_prose(path.read_text()))]


@pytest.mark.parametrize("doc", [README, *DOCS], ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(doc: Path) -> None:
    bad = []
    for target in _links(doc):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        dest = (doc.parent / file).resolve() if file else doc
        if not dest.exists():
            bad.append(f"{target}: no such file {dest}")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            bad.append(f"{target}: no heading with anchor #{anchor} in {dest.name}")
    assert not bad, f"{doc.name}: " + "; ".join(bad)


def _commands() -> list[list[str]]:
    """argv of every tvsctl/tvsd invocation in the README's sh blocks (continuations joined,
    comments and shell operators cut; `sudo`, `nice`, `flock LOCK`, `.venv/bin/` stripped)."""
    found = []
    for lang, body in FENCE.findall(README.read_text()):
        if lang != "sh":
            continue
        for line in body.replace("\\\n", " ").splitlines():
            lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|()")
            lexer.whitespace_split = True
            lexer.commenters = "#"
            words: list[str] = []
            for token in [*lexer, ";"]:
                if token and set(token) <= set(";&|()"):
                    found += _invocation(words)
                    words = []
                else:
                    words.append(token)
    return found


def _invocation(words: list[str]) -> list[list[str]]:
    words = [w for w in words if not re.match(r"\d*[<>]", w)]  # redirections: the shell's
    while words and words[0] in ("sudo", "nice", "-n", "5", "chrt", "-f", "40", "until", "do", "env"):
        words = words[1:]
    if words[:1] == ["flock"]:
        words = words[2:]
    if words and Path(words[0]).name in ("tvsctl", "tvsd") and "=" not in words[0]:
        return [[Path(words[0]).name, *words[1:]]]
    return []


def test_the_readme_shows_commands() -> None:
    names = {argv[0] for argv in _commands()}
    assert names == {"tvsctl", "tvsd"}, names
    assert len(_commands()) > 30


@pytest.mark.slow  # the parsers import each command's module (numba kernels): 6-45 s in all under load
@pytest.mark.parametrize("argv", _commands(), ids=lambda a: " ".join(a)[:70])
def test_readme_command_parses(argv: list[str]) -> None:
    prog, *args = argv
    try:
        if prog == "tvsd":
            parse_tvsd(args)
        else:
            build_parser(args).parse_args(args)
    except SystemExit as exc:  # argparse's refusal (2); --help or --version would be 0
        pytest.fail(f"`{' '.join(argv)}` is refused by the parser (exit {exc.code})")
