"""Where numba keeps tvsd's compiled kernels: under a fingerprint of the sources they freeze.

Numba decides whether a cached kernel is still good from the mtime and size of the file that
defines it, and nothing else. A kernel, though, freezes the module constants it reads from other
files (the runner indexes shared words by `latency.K_*`) and inlines the kernels it calls from
other files (the runner steps `plant.advance`). After a change to those files alone, numba would load
the stale kernel, which then reads and writes the wrong words. A `git pull` that touches
latency.py but not runner.py does exactly that.

So the cache directory is named by a hash of every tvsd file that defines a kernel and of every tvsd
module those files import. Any change there starts a new cache; older ones under the same base are
removed then, so they do not pile up.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import sys
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
_PREFIX = "kernels-"
_KERNEL = re.compile(r"^@(numba\.)?njit\b", re.MULTILINE)
_IMPORT = re.compile(
    r"^(?:from (?P<module>tvsd[\w.]*) import (?P<names>\([^)]*\)|[^\n]+)|import (?P<plain>tvsd[\w.]*))",
    re.MULTILINE,
)


def _module_file(package: Path, name: str) -> Path | None:
    """The source file of module `name` (tvsd.a.b) inside `package`, if there is one."""
    rel = Path(*name.split(".")[1:])
    for cand in (package / rel.with_suffix(".py"), package / rel / "__init__.py"):
        if cand.is_file():
            return cand
    return None


def _imported_files(package: Path, text: str) -> set[Path]:
    """Files of the tvsd modules a module imports at its top level (where a kernel's globals come
    from); `from tvsd.m import x` may name a submodule x."""
    out: set[Path] = set()
    for m in _IMPORT.finditer(text):
        if m["plain"]:
            names = [m["plain"]]
        else:
            parts = [part.split()[0] for part in m["names"].strip("()").split(",") if part.strip()]
            names = [m["module"], *(f"{m['module']}.{part}" for part in parts)]
        out.update(path for name in names if (path := _module_file(package, name)) is not None)
    return out


def fingerprint(package: Path = _PACKAGE) -> str:
    """Hash of the kernel-defining sources and the tvsd modules they import (16 hex digits)."""
    files: set[Path] = set()
    for path in package.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        if _KERNEL.search(text):
            files.add(path)
            files |= _imported_files(package, text)
    digest = hashlib.sha256()
    for path in sorted(files):
        digest.update(str(path.relative_to(package)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def point_numba_cache(package: Path = _PACKAGE) -> Path:
    """Point numba's cache at <base>/kernels-<fingerprint> and return that directory. The base is
    NUMBA_CACHE_DIR if the environment sets it (the systemd unit does), else the package's
    __pycache__. The variable is rewritten so that child processes (the SIL twins, tests' daemons)
    share the directory; a process that inherits it keeps its base."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    base = Path(env) if env else package / "__pycache__" / "numba"
    if base.name.startswith(_PREFIX):
        base = base.parent
    target = base / f"{_PREFIX}{fingerprint(package)}"
    if not target.is_dir() and base.is_dir():
        for old in base.glob(f"{_PREFIX}*"):  # for sources that no longer exist here
            shutil.rmtree(old, ignore_errors=True)
    os.environ["NUMBA_CACHE_DIR"] = str(target)
    if "numba" in sys.modules:  # imported before tvsd: its config has read the variable already
        from numba.core import config

        setattr(config, "CACHE_DIR", str(target))  # noqa: B010 (set by numba at run time: not in its stubs)
    return target
