"""The MCU's side of the link handshake, played in Python on a pty's master by the tests that
check the host without firmware (tests/test_mcu_link.py's FakeMcu, tests/test_late_input.py's
PacedMcu): reading the host's frames, and answering identify, heartbeat and stats as the
firmware does. What else each fake does (recording, pacing, holding frames back) stays in it."""

from __future__ import annotations

import os
from collections.abc import Callable

from tvsd.hw.mcu.framing import Frame, FrameDecoder
from tvsd.hw.mcu.spec import load_spec

SPEC = load_spec()
ID = {m.name: m for m in SPEC.messages}
HZ = 16_000_000  # the MCU's tick rate, as identify reports it


def read_host_frames(master: int, decoder: FrameDecoder) -> list[Frame]:
    """The host's frames completed by what the pty's master holds now ([] once it is closed)."""
    try:
        data = os.read(master, 65536)
    except OSError:
        return []
    return decoder.feed(data)


def answer_handshake(
    frame: Frame,
    decoder: FrameDecoder,
    send: Callable[..., object],
    ticks: Callable[[], int],
    *,
    board: int,
    version: int = SPEC.version,
    table_hash: int = SPEC.table_hash,
) -> None:
    """Answer one host frame as the firmware does, through `send(name, *values)`: identify_req
    -> identify (`version`, HZ, `table_hash`, `board`), heartbeat -> heartbeat_ack (its host_us,
    `ticks()` mod 2**32), stats_req -> stats (the frames `decoder` has counted, no errors). Any
    other frame gets no answer."""
    name = SPEC.by_id(frame.msg_id).name  # type: ignore[union-attr]
    if name == "identify_req":
        send("identify", version, HZ, table_hash, board)
    elif name == "heartbeat":
        (host_us,) = ID["heartbeat"].codec.unpack(frame.payload)
        send("heartbeat_ack", host_us, ticks() & 0xFFFF_FFFF)
    elif name == "stats_req":
        send("stats", decoder.stats.frames, 0, 0, 0, 0, 0, 0, 0)
