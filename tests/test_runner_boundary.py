"""Outside tvsd/control, the 10 kHz loop is steered through `Runner`'s methods only.

The loop's shared arrays (`vals`, `ints`, `rec`, `hist`) and their word numbers (words' V_*, K_*,
R_*, latency's K_*, the law's layout) are control's own: a word renumbered there must not silently
break a caller elsewhere. This greps the package and the tests for any use of them.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CONTROL = ROOT / "tvsd" / "control"
WORD_MODULES = ("runner", "words", "kernel", "link_tx", "latency", "layout")
# The public names of those modules that are not words.
PUBLIC = {"TICK_DTYPE", "TICK_FIELDS", "EXTRAPOLATE_MAX_NS", "LATCH_OFF", "BINS_PER_DECADE"}
ALLOWED = {
    # The offline simulation's own kernel runs the law on its own controller array: it reads the
    # law's words from the one layout (that is the point of having one).
    ROOT / "tvsd" / "sim" / "closed_loop.py": {"layout"},
    # Unit tests of latency's timing primitives on their own arrays (no runner involved).
    ROOT / "tests" / "test_latency.py": {"latency", "arrays"},
    # A made-up package's `words` module (the kernel cache's fingerprint test), not ours.
    ROOT / "tests" / "test_kernel_cache.py": {"words"},
    # This file's own examples.
    Path(__file__).resolve(): {"runner", "latency", "layout", "arrays"},
}

# not a call: matplotlib's `ax.hist(...)` is a method, the runner's arrays are indexed
ARRAYS = re.compile(r"(?<!args)\.(vals|ints|rec|hist)\b(?!\s*=\s*np\.)(?!\s*\()")
ALIAS = re.compile(
    r"from tvsd\.control import (?P<mod>\w+) as (?P<alias>\w+)"
    r"|import tvsd\.control\.(?P<mod2>\w+) as (?P<alias2>\w+)"
)
FROM_IMPORT = re.compile(r"from tvsd\.control\.(?P<mod>\w+) import (?P<names>\([^)]*\)|[^\n]+)")
WORD = re.compile(r"^[A-Z][A-Z0-9_]*$")


def _files() -> list[Path]:
    package = [p for p in (ROOT / "tvsd").rglob("*.py") if CONTROL not in p.parents]
    return package + sorted((ROOT / "tests").glob("*.py"))


def violations(path: Path, text: str) -> list[str]:
    allowed = ALLOWED.get(path.resolve(), set())
    found = []
    if "arrays" not in allowed:
        for m in ARRAYS.finditer(text):
            found.append(f"the runner's array `.{m[1]}`")
    for m in ALIAS.finditer(text):
        mod, alias = (m["mod"], m["alias"]) if m["mod"] else (m["mod2"], m["alias2"])
        if mod in WORD_MODULES and mod not in allowed:
            for word in set(re.findall(rf"\b{alias}\.([A-Z][A-Z0-9_]*)\b", text)) - PUBLIC:
                found.append(f"{mod}'s word {alias}.{word}")
    for m in FROM_IMPORT.finditer(text):
        if m["mod"] in WORD_MODULES and m["mod"] not in allowed:
            names = {n.split()[0] for n in m["names"].strip("()").split(",") if n.strip()}
            found += [f"{m['mod']}'s word {n}" for n in sorted(names) if WORD.match(n) and n not in PUBLIC]
    return found


def test_no_loop_word_or_shared_array_is_used_outside_control() -> None:
    bad = {str(p.relative_to(ROOT)): v for p in _files() if (v := violations(p, p.read_text()))}
    assert not bad, f"use the Runner's methods (tvsd/control/runner.py) instead: {bad}"


@pytest.mark.parametrize(
    "text",
    [
        "x = runner.vals[3]\n",
        "runner.ints[9] = 0\n",
        "n = self.runner.rec.shape[0]\n",
        "from tvsd.control import runner as RN\nu = RN.V_GP\n",
        "import tvsd.control.latency as lat\nk = lat.K_TICKS\n",
        "from tvsd.control.runner import (\n    V_OMEGA,\n    Runner,\n)\n",
    ],
)
def test_the_check_sees_each_kind_of_use(text: str) -> None:
    assert violations(ROOT / "tvsd" / "daemon" / "x.py", text)


def test_the_public_api_passes() -> None:
    text = (
        "from tvsd.control.runner import TICK_DTYPE, LoopFault, Runner\n"
        "rows = runner.recent_ticks(10)\nrunner.set_gains(g)\nargs.rec\n"
    )
    assert violations(ROOT / "tvsd" / "daemon" / "x.py", text) == []
