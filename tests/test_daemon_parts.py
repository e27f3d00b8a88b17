"""The daemon's parts on their own: the state table, the fault log, the status's JSON contract."""

from __future__ import annotations

import dataclasses
import math

import pytest

from tvsd.daemon.faults import FaultKind, FaultLog
from tvsd.daemon.state import TRANSITIONS, DaemonState, IllegalTransition, StateMachine
from tvsd.daemon.status import Aim, LoopStatus, PointsStatus, Status
from tvsd.errors import EXIT_INTERNAL

S = DaemonState


def _at(state: DaemonState) -> StateMachine:
    m = StateMachine()
    m.state = state
    return m


@pytest.mark.parametrize("old,new", [(o, n) for o, targets in TRANSITIONS.items() for n in targets])
def test_each_transition_of_the_table_is_taken_and_told(old: DaemonState, new: DaemonState) -> None:
    seen: list[tuple[DaemonState, DaemonState]] = []
    m = _at(old)
    m.on_change = lambda a, b: seen.append((a, b))
    m.go(new)
    assert m.state == new and seen == [(old, new)]


@pytest.mark.parametrize(
    "old,new",
    [(o, n) for o in S for n in S if n != o and n not in TRANSITIONS[o]],
)
def test_every_other_transition_is_refused_naming_both_states(old: DaemonState, new: DaemonState) -> None:
    m = _at(old)
    with pytest.raises(IllegalTransition, match=f"daemon state {old} cannot go to {new}") as info:
        m.go(new)
    assert m.state == old and info.value.exit_status == EXIT_INTERNAL


def test_the_table_covers_every_state_and_the_contract_strings() -> None:
    assert set(TRANSITIONS) == set(S)
    assert [str(s) for s in S] == ["starting", "idle", "spinning", "scanning", "fault", "stopping"]
    assert all(S.STOPPING in TRANSITIONS[s] for s in S if s != S.STOPPING)  # shutdown from anywhere


def test_can_answers_as_go_would() -> None:
    for old in S:
        for new in S:
            assert _at(old).can(new) == (new == old or new in TRANSITIONS[old])
    assert not _at(S.STOPPING).can(S.SCANNING) and _at(S.SPINNING).can(S.SCANNING)


def test_staying_put_is_silent() -> None:
    m = _at(S.FAULT)
    m.on_change = lambda a, b: pytest.fail("no change")
    m.go(S.FAULT)


def test_the_fault_log_is_a_ring_with_counts_that_survive_clear() -> None:
    log = FaultLog(capacity=3)
    for i in range(5):
        log.add(FaultKind.IMU, f"IMU lost #{i}", "scanning continues")
    log.add(FaultKind.MCU_STALE, "MCU state frames stopped", "PWM 0", safe_after_ms=40.1)
    assert [e.cause for e in log.entries()] == ["IMU lost #3", "IMU lost #4", "MCU state frames stopped"]
    assert log.counts() == {"imu": 5, "mcu_stale": 1}
    assert log.clear() == 3 and len(log) == 0 and log.entries() == []
    assert log.counts() == {"imu": 5, "mcu_stale": 1}


def test_a_fault_entry_keeps_its_json_fields_and_adds_its_kind() -> None:
    entry = FaultLog(1).add(FaultKind.MCU_STALE, "stopped", "PWM 0", safe_after_ms=40.0)
    j = entry.to_json()
    assert list(j) == ["t_unix", "cause", "action", "safe_after_ms", "kind"]
    assert j["kind"] == "mcu_stale" and type(j["kind"]) is str and j["safe_after_ms"] == 40.0
    # written field by field (asdict's deep copy cost ~0.1 ms an entry): none may be left out
    assert j == {**dataclasses.asdict(entry), "kind": "mcu_stale"}


def test_status_json_has_the_contracts_shape() -> None:
    log = FaultLog(4)
    log.add(FaultKind.IMU, "IMU lost", "flagged")
    status = Status(
        state=S.SCANNING,
        rps=25.0,
        rps_setpoint=25.0,
        loop=LoopStatus(10_000.0, 3, 12.5, 80.0, 123_456),
        imu={"source": "sil", "state": "ok"},
        link={"source": "sil", "state": "ok"},
        points=PointsStatus(10, 1, 24.9),
        recording=None,
        aim_deg=Aim(60.0, 0.0),
        faults=log.entries(),
        fault_counts=log.counts(),
        realtime=None,
        rpc={"clients": 1},
    )
    j = status.to_json()
    assert list(j) == [
        "state", "rps", "rps_setpoint", "loop", "imu", "link", "points", "recording", "aim_deg",
        "faults", "fault_counts", "realtime", "rpc", "measurement_age_ms", "stale",
    ]  # fmt: skip
    assert j["state"] == "scanning" and type(j["state"]) is str
    assert j["loop"] == {
        "rate_hz": 10_000.0, "missed_ticks": 3, "jitter_p99_us": 12.5, "jitter_max_us": 80.0, "ticks": 123_456
    }  # fmt: skip
    assert j["points"] == {"total": 10, "no_imu": 1, "per_s": 24.9}  # no latency yet: absent
    assert j["aim_deg"] == {"phi": 60.0, "gamma": 0.0} and j["faults"][0]["cause"] == "IMU lost"
    assert "scanning" in status.line() and "faults 1" in status.line()
    with_latency = PointsStatus(10, 1, 24.9, 2.0, 5.0).to_json()
    assert with_latency["latency_p50_ms"] == 2.0 and with_latency["latency_max_ms"] == 5.0
    idle = Status(**{**status.__dict__, "loop": LoopStatus(math.nan, 0, math.nan, math.nan, 0)})
    assert "p99    0.0 µs" in idle.line()  # no tick yet


class _Imu:
    def __init__(self) -> None:
        self.healthy, self.state = True, "ok"


class _Drive:
    """The DriveLink calls a scan session makes; `synced`: whether the MCU clock map is ready."""

    clock_hz = 16e6

    def __init__(self) -> None:
        self.synced = False

    def to_mcu_s(self, host_s: float) -> float:
        return host_s if self.synced else math.nan

    def sent_volts(self, t_mcu):  # type: ignore[no-untyped-def]
        return t_mcu * 0.0


def _scanning_daemon():  # type: ignore[no-untyped-def]
    """A Daemon's scan logic without its devices: the IMU ok, the MCU clock not synced yet."""
    from tvsd.config import load_config
    from tvsd.daemon.app import Daemon
    from tvsd.daemon.scan_session import PointCounters

    d = object.__new__(Daemon)
    d.cfg, d.imu, d.drive, d.web, d.recording = load_config(), _Imu(), _Drive(), None, None
    d.aim_deg, d.points, d.scan, d.scan_why = (60.0, 0.0), PointCounters(), None, None
    d._state = _at(S.SCANNING)
    return d


def test_points_are_made_uncompensated_until_the_mcu_clock_syncs_then_compensated() -> None:
    """Without the host → MCU clock map the SA samples cannot be placed against the pulses: a
    compensated session would wait for them for ever (0 points while 'scanning', IMU ok). The
    daemon scans uncompensated, says why, and switches at the first IMU batch after the sync."""
    import numpy as np

    from tvsd.hw.imu_sensor_reader import ImuBatch

    d = _scanning_daemon()
    d._new_scan()
    assert not d.scan.compensated and "clock sync" in d._points_status().to_json()["uncompensated_why"]
    none = np.zeros((0, 3))
    batch = ImuBatch("pl", np.zeros(0, dtype=np.int64), 0, np.zeros(0), none, none, np.zeros((0, 6)))
    d._on_imu_batch(batch)
    assert not d.scan.compensated  # still no clock: the same session goes on
    d.drive.synced = True
    d._on_imu_batch(batch)
    st = d._points_status().to_json()
    assert d.scan.compensated and st["compensated"] is True and "uncompensated_why" not in st
    d.imu.healthy, d.imu.state = False, "lost"
    d._on_imu_batch(batch)
    assert not d.scan.compensated and d._points_status().uncompensated_why == "IMU lost"


def test_the_points_status_says_nothing_of_compensation_when_not_scanning() -> None:
    d = _scanning_daemon()
    assert set(d._points_status().to_json()) == {"total", "no_imu", "per_s"}
