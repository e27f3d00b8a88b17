"""Install from a wheel (README "On the scanner"): build the wheel from this checkout,
install it into a fresh venv outside the checkout, and run `tvsctl mcu identify --sil` and
`tvsd --sil` from there, with the config in an /etc/tvsd-like directory.

What it proves: the wheel carries the protocol spec (tvsd/hw/mcu/protocol.yaml) and the firmware
core compiled for the host (tvsd/sim/_vmcu*.so, built by setup.py at wheel-build time), so nothing
is read from or built in the source tree at run time.

Dependencies: by default the fresh venv gets the wheel alone (`pip install --no-deps`) and sees the
third-party packages already installed for this test run through a .pth file (numba, scipy and
matplotlib would take minutes to unpack again on a loaded 2-core machine); the test then checks
that every requirement the wheel declares is satisfied there. TVSD_WHEEL_FULL_INSTALL=1 installs
them with pip instead (PyPI or the pip cache).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import sysconfig
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import wait_for

from tvsd.errors import DeviceError
from tvsd.sim import virtual_mcu as vm
from tvsd.sim import vmcu_library

ROOT = Path(__file__).resolve().parents[1]
START_S = 180.0  # the fresh install compiles the numba kernels on first start (loaded machine)
POLL_S = 0.2


def _run(argv: list[str | Path], cwd: Path, env: dict[str, str] | None = None, timeout: float = 600) -> str:
    proc = subprocess.run(
        [str(a) for a in argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert proc.returncode == 0, (
        f"{argv}: exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    )
    return proc.stdout


def _clean_env(base: Path) -> dict[str, str]:
    """No trace of the checkout: no PYTHONPATH, no inherited numba cache, config in base/etc/tvsd."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "NUMBA_", "TVSD_"))}
    env["TVSD_CONFIG_DIR"] = str(base / "etc" / "tvsd")
    env["HOME"] = str(base / "home")
    return env


@pytest.fixture(scope="module")
def venv(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path]]:
    base = tmp_path_factory.mktemp("wheel-install")
    (base / "home").mkdir()
    dist = base / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", dist, ROOT], cwd=base)
    (wheel,) = dist.glob("tvsd-*.whl")
    assert "linux" in wheel.name, f"{wheel.name}: the wheel must be platform-specific (it holds a .so)"
    env = base / "venv"
    _run([sys.executable, "-m", "venv", env], cwd=base)
    py = env / "bin" / "python"
    if os.environ.get("TVSD_WHEEL_FULL_INSTALL"):
        _run([py, "-m", "pip", "install", "-q", wheel], cwd=base)
    else:
        _run([py, "-m", "pip", "install", "-q", "--no-deps", wheel], cwd=base)
        site = Path(
            _run([py, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], cwd=base).strip()
        )
        # after the venv's own site-packages on sys.path: the wheel's tvsd is found first
        (site / "zz_test_deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    # /etc/tvsd as the README installs it
    shutil.copytree(ROOT / "config", base / "etc" / "tvsd")
    yield env / "bin", base


@pytest.mark.slow
def test_the_installed_package_is_the_wheel_and_carries_spec_and_core(venv: tuple[Path, Path]) -> None:
    bindir, base = venv
    probe = (
        "import importlib.metadata as md, json, re, tvsd\n"
        "from tvsd.hw.mcu.spec import load_spec\n"
        "from tvsd.sim.virtual_mcu import default_library\n"
        "dist = md.distribution('tvsd')\n"
        "reqs = [r for r in dist.requires or [] if 'extra ==' not in r]\n"
        "missing = []\n"
        "for r in reqs:\n"
        "    name = re.split(r'[<>=!~ ;\\[]', r, maxsplit=1)[0]\n"
        "    try: md.distribution(name)\n"
        "    except md.PackageNotFoundError: missing.append(name)\n"
        "print(json.dumps({'tvsd': tvsd.__file__, 'spec': str(load_spec().path),\n"
        "                  'version': load_spec().version, 'lib': str(default_library()),\n"
        "                  'reqs': len(reqs), 'missing': missing}))\n"
    )
    out = json.loads(_run([bindir / "python", "-c", probe], cwd=base, env=_clean_env(base)))
    site = str(bindir.parent)
    assert out["tvsd"].startswith(site) and not out["tvsd"].startswith(str(ROOT))
    assert out["spec"].startswith(site) and out["spec"].endswith("tvsd/hw/mcu/protocol.yaml")
    assert out["lib"].startswith(site) and "/tvsd/sim/_vmcu" in out["lib"]
    assert out["reqs"] >= 5 and out["missing"] == []


@pytest.mark.slow
def test_tvsctl_mcu_identify_sil_from_the_wheel(venv: tuple[Path, Path]) -> None:
    bindir, base = venv
    out = json.loads(
        _run(
            [bindir / "tvsctl", "mcu", "identify", "--sil", "--json"],
            cwd=base,
            env=_clean_env(base),
            timeout=120,
        )
    )
    from tvsd.hw.mcu.spec import load_spec

    spec = load_spec()
    assert out["match"] is True and out["board"] == "host"
    assert out["proto_version"] == spec.version and out["table_hash"] == f"0x{spec.table_hash:08X}"


def _status(sock: Path) -> dict:
    """The daemon's status; while its first start compiles the kernels it may not answer in
    time: that reads as "not up yet", the wait goes on."""
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(10)
            s.connect(str(sock))
            f = s.makefile("rwb")
            f.write(b'{"jsonrpc": "2.0", "id": 1, "method": "status", "params": {}}\n')
            f.flush()
            return json.loads(f.readline())["result"]
    except OSError:  # TimeoutError included
        return {"state": "no answer", "link": {"state": "no answer"}, "faults": []}


@pytest.mark.slow
def test_tvsd_sil_from_the_wheel_brings_the_link_up(venv: tuple[Path, Path]) -> None:
    bindir, base = venv
    sock, data, log = base / "run" / "tvsd.sock", base / "data", base / "tvsd.log"
    with log.open("w") as log_file:
        proc = subprocess.Popen(
            [bindir / "tvsd", "--sil", "--socket", sock, "--data-dir", data],
            cwd=base,
            env=_clean_env(base),
            stdout=log_file,
            stderr=log_file,
        )
    try:
        wait_for(
            lambda: sock.exists() or proc.poll() is not None, START_S, "the daemon's socket", interval=POLL_S
        )
        assert proc.poll() is None, log.read_text()[-3000:]
        st = wait_for(
            lambda: _status(sock),
            START_S,
            "the MCU link up",
            ok=lambda s: s["link"]["state"] == "ok",
            interval=POLL_S,
        )
        assert st["state"] != "fault", st["faults"]
        _run([bindir / "tvsctl", "shutdown", "--socket", sock], cwd=base, env=_clean_env(base), timeout=60)
        assert proc.wait(30) == 0, log.read_text()[-3000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_a_missing_core_library_is_one_clear_line(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Outside a checkout, with no compiled core in the package: an error that says what and how to
    fix, and nothing is compiled."""
    monkeypatch.setattr(vmcu_library, "FIRMWARE_DIR", tmp_path / "no-firmware")
    monkeypatch.setattr(vmcu_library, "packaged_library", lambda: None)
    with pytest.raises(DeviceError, match=r"no virtual MCU library .*reinstall from a wheel built") as info:
        vm.default_library()
    assert "\n" not in str(info.value)


def test_without_a_firmware_tree_the_stm32_image_is_one_line_and_its_bench_is_skipped(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """From the installed wheel `tvsctl bench --only mcu_stm32` ran make in
    site-packages/firmware: a two-line "building ... failed" with make's "No such file or
    directory", exit 3, and a whole `tvsctl bench` stopped there. Now the group says what it needs,
    and building the image is one line naming the checkout."""
    from tvsd.sim import emulator, qemu_mcu, stm32_bench

    monkeypatch.setattr(emulator, "FIRMWARE_DIR", tmp_path / "site-packages" / "firmware")
    monkeypatch.setattr(qemu_mcu, "missing_tools", list)
    assert stm32_bench.bench_stm32() == {
        "mcu_stm32_skipped": "needs a source checkout's firmware/ (make -C firmware bench-stm32)"
    }
    needs = r"source checkout's firmware/.*make -C firmware stm32"
    with pytest.raises(qemu_mcu.QemuMcuError, match=needs) as info:
        qemu_mcu.build_image()
    assert "\n" not in str(info.value)


def test_outside_a_checkout_the_shipped_configs_stand_in_for_a_missing_etc_tvsd(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A plain `pip install tvsd-*.whl` then `tvsctl sim step --ref-deg 5`: "/etc/tvsd/tvsd.yaml: no
    such config file; check the path (see config/ for examples)" — and an installed wheel has no
    config/. The wheel carries config/*.yaml (setup.py → tvsd/config/shipped); /etc/tvsd and
    $TVSD_CONFIG_DIR still win when they hold a config."""
    from tvsd.config import load as L

    shipped, etc = tmp_path / "shipped", tmp_path / "etc"
    shutil.copytree(ROOT / "config", shipped)
    monkeypatch.delenv("TVSD_CONFIG_DIR", raising=False)
    monkeypatch.setattr(L, "CHECKOUT_DIR", tmp_path / "no-checkout")
    monkeypatch.setattr(L, "SHIPPED_DIR", shipped)
    monkeypatch.setattr(L, "ETC_DIR", etc)
    assert L.config_dir() == shipped
    assert L.load_config(params="paper") == L.load_config(ROOT / "config" / "paper.yaml")
    etc.mkdir()
    (etc / "tvsd.yaml").write_text((ROOT / "config" / "tvsd.yaml").read_text())
    assert L.config_dir() == etc  # the installed config wins
    monkeypatch.setenv("TVSD_CONFIG_DIR", str(tmp_path / "mine"))
    assert L.config_dir() == tmp_path / "mine"
    shutil.rmtree(shipped)
    monkeypatch.delenv("TVSD_CONFIG_DIR")
    shutil.rmtree(etc)
    assert L.config_dir() == etc  # nothing anywhere: the error names /etc/tvsd, as before


@pytest.mark.slow
def test_the_wheel_carries_the_configs_and_sim_runs_without_etc_tvsd(venv: tuple[Path, Path]) -> None:
    bindir, base = venv
    if Path("/etc/tvsd/tvsd.yaml").exists():
        pytest.skip("this machine has /etc/tvsd/tvsd.yaml, which wins over the shipped copies")
    env = _clean_env(base)
    del env["TVSD_CONFIG_DIR"]
    out = json.loads(_run([bindir / "tvsctl", "sim", "step", "--ref-deg", "5", "--json"], cwd=base, env=env))
    assert out["ref_deg"] == 5 and out["settling_time_s"] > 0
    probe = "from tvsd.config import config_dir; print(config_dir())"
    where = _run([bindir / "python", "-c", probe], cwd=base, env=env).strip()
    assert where.startswith(str(bindir.parent)) and where.endswith("tvsd/config/shipped")
