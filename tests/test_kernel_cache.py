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
