"""Branch splits3's proof of no behaviour change, by the code: every top-level definition of the old
instrument.py and noise.py (functions, classes, constants) is in instrument.py, instrument_maps.py,
noise.py or peak.py with an equal AST, docstrings included, after two renames (noise._peak →
peak.fit_peak, noise._seen_height → peak.seen_height: imported across modules now).
docs/measurements/splits3.md.

    mkdir -p /tmp/splits3_old && git archive integ3 tvsd | tar -x -C /tmp/splits3_old
    .venv/bin/python scripts/splits3_ast_check.py /tmp/splits3_old/tvsd/analysis tvsd/analysis
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

OLD_MODULES = ("instrument.py", "noise.py")
NEW_MODULES = ("instrument.py", "instrument_maps.py", "noise.py", "peak.py")
RENAME = {"_peak": "fit_peak", "_seen_height": "seen_height"}


def norm(node: ast.AST) -> str:
    src = ast.unparse(node)
    for a, b in RENAME.items():
        src = re.sub(r"\b" + a + r"\b", b, src)
    return ast.dump(ast.parse(src))


def defs(path: Path) -> dict[str, ast.AST]:
    out: dict[str, ast.AST] = {}
    for n in ast.parse(path.read_text()).body:
        if isinstance(n, (ast.FunctionDef, ast.ClassDef)):
            out[n.name] = n
        elif isinstance(n, (ast.Assign, ast.AnnAssign)):
            target = n.targets[0] if isinstance(n, ast.Assign) else n.target
            if isinstance(target, ast.Name):
                out[target.id] = n
    return out


def main() -> int:
    old_dir, new_dir = Path(sys.argv[1]), Path(sys.argv[2])
    new: dict[str, list[tuple[str, ast.AST]]] = {}
    for mod in NEW_MODULES:
        for name, node in defs(new_dir / mod).items():
            new.setdefault(name, []).append((mod, node))
    bad = checked = 0
    known: set[str] = set()
    for mod in OLD_MODULES:
        for name, node in defs(old_dir / mod).items():
            checked += 1
            now = RENAME.get(name, name)
            known.add(now)
            homes = [m for m, v in new.get(now, []) if norm(v) == norm(node)]
            if len(homes) != 1:
                bad += 1
                print(f"{mod}:{name}: " + ("changed or missing" if not homes else "in " + ", ".join(homes)))
            elif homes[0] != mod:
                print(f"moved  {mod}:{name} -> {homes[0]}:{now}")
    extra = sorted(f"{m}:{k}" for k, vs in new.items() if k not in known for m, _ in vs)
    for e in extra:
        print(f"new    {e}")
    print(f"{checked} definitions checked, {bad} changed or missing, {len(extra)} new")
    return 1 if bad or extra else 0


if __name__ == "__main__":
    sys.exit(main())
