"""The hardware-in-the-loop files import on a machine without the hardware.

hil/ runs only beside the real scanner, so neither CI nor `make lint` reads it: a rename in tvsd
can break it unseen. hil/test_mcu_hil.py imported `LinkSettings` from tvsd.hw.mcu.link long
after it became `McuSettings` (ec9f0d6), and could not even be collected. Importing each file here
(its tests still skip without TVSD_MCU_PORT and the IMU bus) catches that in the suite.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

HIL = Path(__file__).resolve().parent.parent / "hil"


@pytest.mark.parametrize("path", sorted(HIL.glob("test_*.py")), ids=lambda p: p.name)
def test_a_hil_file_imports(path: Path) -> None:
    spec = importlib.util.spec_from_file_location(f"hil_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    spec.loader.exec_module(importlib.util.module_from_spec(spec))
