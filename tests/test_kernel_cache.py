"""The numba cache directory follows the sources a kernel freezes, not just the file defining it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tvsd import _kernel_cache as KC


def _package(root: Path) -> Path:
    """A tiny tvsd-like package: a kernel reading a constant from another module, and a bystander."""
    pkg = root / "tvsd"
    (pkg / "control").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "control" / "__init__.py").write_text("")
    (pkg / "control" / "words.py").write_text("K_TICKS = 3\n")
    (pkg / "control" / "loop.py").write_text(
        "from numba import njit\n\nfrom tvsd.control import words as W\n\n\n"
        "@njit(cache=True)\ndef tick(ints):\n    ints[W.K_TICKS] += 1\n"
    )
    (pkg / "cli.py").write_text("import argparse\n")
    return pkg


def test_fingerprint_follows_a_constant_the_kernel_imports(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    first = KC.fingerprint(pkg)
    (pkg / "cli.py").write_text("import argparse  # edited\n")
    assert KC.fingerprint(pkg) == first, "a module no kernel imports must not invalidate the kernels"
    (pkg / "control" / "words.py").write_text("K_PERIOD, K_TICKS = 3, 4\n")
    assert KC.fingerprint(pkg) != first, "the kernel froze K_TICKS: its cache must not survive the change"


def test_parenthesised_imports_name_submodules(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    text = "from tvsd.control import (\n    loop as L,\n    words,\n)\n"
    assert KC._imported_files(pkg, text) == {
        pkg / "control" / "__init__.py",
        pkg / "control" / "loop.py",
        pkg / "control" / "words.py",
    }


def test_cache_dir_is_named_by_fingerprint_and_old_ones_go(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from numba.core import config

    monkeypatch.setattr(config, "CACHE_DIR", config.CACHE_DIR)  # put back after: the suite's kernels
    pkg = _package(tmp_path)
    base = tmp_path / "cache"
    stale = base / "kernels-0000000000000000"
    stale.mkdir(parents=True)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(base))
    target = KC.point_numba_cache(pkg)
    assert target == base / f"kernels-{KC.fingerprint(pkg)}"
    assert os.environ["NUMBA_CACHE_DIR"] == str(target) == config.CACHE_DIR
    assert not stale.exists()
    # A child process inherits the pointed directory and keeps it, not a directory inside it.
    target.mkdir()
    assert KC.point_numba_cache(pkg) == target and target.is_dir()


def test_this_process_uses_the_fingerprinted_cache() -> None:
    from numba.core import config

    assert Path(config.CACHE_DIR).name == f"kernels-{KC.fingerprint()}"


def test_a_user_who_cannot_write_the_package_still_runs_kernels(tmp_path: Path) -> None:
    """An installed package is root's; a user running `tvsctl analyze` from it cannot write its
    __pycache__: numba found no cache locator and every kernel module's import raised (exit 70).
    Run as `nobody` (no writable home) with the package's cache dir not writable."""
    import shutil
    import subprocess
    import sys

    setpriv = shutil.which("setpriv")
    if os.geteuid() != 0 or setpriv is None:
        pytest.skip("needs root and setpriv to run a process as another user")
    as_nobody = [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable, "-c"]
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["HOME"] = "/nonexistent"
    probe = subprocess.run([*as_nobody, "import numba"], cwd="/", env=env, capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"nobody cannot run this interpreter: {probe.stderr.decode()[-200:]}")
    run = subprocess.run(
        [*as_nobody, "import os, tvsd.model.lugre; print(os.environ['NUMBA_CACHE_DIR'])"],
        cwd="/", env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-1000:]
    assert Path(run.stdout.strip()).parent.name == "tvsd-numba-65534"
