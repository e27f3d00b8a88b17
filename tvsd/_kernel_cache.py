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
import tempfile
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
    if not _writable(base):
        # an installed package (root-owned site-packages) run by a user: numba would find no
        # place to cache and every kernel's import would raise (`tvsctl analyze` exited 70)
        base = _user_base()
    target = base / f"{_PREFIX}{fingerprint(package)}"
    if not target.is_dir() and base.is_dir():
        for old in base.glob(f"{_PREFIX}*"):  # for sources that no longer exist here
            shutil.rmtree(old, ignore_errors=True)
    os.environ["NUMBA_CACHE_DIR"] = str(target)
    if "numba" in sys.modules:  # imported before tvsd: its config has read the variable already
        from numba.core import config

        setattr(config, "CACHE_DIR", str(target))  # noqa: B010 (set by numba at run time: not in its stubs)
    return target


def _writable(path: Path) -> bool:
    """Whether `path` is, or can be made as, a directory this process writes into."""
    for p in (path, *path.parents):
        try:
            os.stat(p)
        except FileNotFoundError:
            continue
        except OSError:  # a parent we may not search
            return False
        return p.is_dir() and os.access(p, os.W_OK | os.X_OK)
    return False


def _user_base() -> Path:
    """The user's own cache ($XDG_CACHE_HOME or ~/.cache), else a directory of this user's in the
    temp dir: made 0700 and checked to be ours, since a cached kernel is code this process runs."""
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    home = Path(xdg) / "tvsd" / "numba"
    if Path(xdg).is_absolute() and _writable(home):
        return home
    own = Path(tempfile.gettempdir()) / f"tvsd-numba-{os.getuid()}"
    try:
        own.mkdir(mode=0o700, exist_ok=True)
        st = own.lstat()
    except OSError:
        return own  # numba says what it cannot do, as before
    if st.st_uid != os.getuid() or not own.is_dir() or own.is_symlink() or st.st_mode & 0o022:
        raise RuntimeError(f"{own} is not this user's private directory: remove it, or set NUMBA_CACHE_DIR")
    return own
