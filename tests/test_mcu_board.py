"""mcu.board: the board the config names sets the exchange rate and must be the one identify reports."""

from __future__ import annotations

from pathlib import Path

import pytest

from tvsd.config import config_dir, load_config
from tvsd.errors import ConfigError, UsageError
from tvsd.hw.mcu.settings import BOARD_EXCHANGE_HZ, McuSettings
from tvsd.hw.mcu.spec import load_spec


def test_each_board_sets_its_exchange_rate() -> None:
    assert McuSettings().board == "atmega328p"
    assert McuSettings().exchange_hz == 2000.0  # protocol v2 at 80 % CPU (simavr)
    assert McuSettings(board="stm32f405").exchange_hz == 10000.0
    assert McuSettings(board="stm32f405", state_rate_hz=5000).exchange_hz == 5000.0
    assert load_config().mcu.exchange_hz == BOARD_EXCHANGE_HZ[load_config().mcu.board]


def test_every_board_has_an_id_in_the_protocol() -> None:
    assert set(BOARD_EXCHANGE_HZ) <= set(load_spec(None).boards.values())


def test_a_rate_beyond_the_board_is_refused_with_the_fix() -> None:
    with pytest.raises(UsageError, match=r"state_rate_hz: the atmega328p carries at most 2000 .* mcu.board"):
        McuSettings(state_rate_hz=10000)


def _with_mcu(tmp_path: Path, line: str) -> Path:
    text = (config_dir() / "tvsd.yaml").read_text()
    assert "  board: atmega328p" in text
    for other in config_dir().glob("*.yaml"):  # the SIL profile it names, beside it
        (tmp_path / other.name).write_text(other.read_text())
    path = tmp_path / "tvsd.yaml"
    path.write_text(text.replace("  board: atmega328p", line, 1))
    return path


def test_an_unknown_board_in_the_config_names_the_line_and_the_choices(tmp_path: Path) -> None:
    path = _with_mcu(tmp_path, "  board: stm32")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert f"{path}:" in msg and "mcu.board" in msg and "atmega328p, stm32f405" in msg and "'stm32'" in msg


def test_the_config_may_name_the_stm32(tmp_path: Path) -> None:
    assert load_config(_with_mcu(tmp_path, "  board: stm32f405")).mcu.exchange_hz == 10000.0


def test_identify_board_is_checked() -> None:
    m = McuSettings(board="stm32f405", port="/dev/ttyACM0")
    assert m.board_problem("stm32f405") is None
    assert m.board_problem("host", sil=True) is None  # the SIL's virtual MCU: the core built for the host
    problem = m.board_problem("atmega328p")
    assert problem is not None
    assert "/dev/ttyACM0 reports board atmega328p but mcu.board is stm32f405" in problem
    assert "set mcu.board: atmega328p" in problem and "flash the stm32f405 image" in problem
    assert m.board_problem("host") is not None  # a host board on real hardware is not this board
