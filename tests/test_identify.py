"""`tvsctl identify`: the excitation table, its config section, the control thread playing it, and
the daemon's identify → export → analyze loop on the SIL plant.

The kernel checks are exact, not timed: every recorded tick carries its wake time on the loop's
clock, and the row it must have played is floor((wake − t0) / period); the command and the speed
reference are rebuilt from what the tick saw (as tests/test_control_runner.py rebuilds the law).
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import wait_for
from test_control_runner import _law

from tvsd.config import IdentifySettings, load_config
from tvsd.control import scanning
from tvsd.control.excitation import build
from tvsd.control.runner import Runner
from tvsd.control.setup import Setup
from tvsd.errors import ConfigError, UsageError
from tvsd.model import params as P

CONFIG = Path(__file__).resolve().parent.parent / "config" / "tvsd.yaml"


# --- config ------------------------------------------------------------------------------------------
def _config_with(tmp_path: Path, section: str) -> Path:
    text = CONFIG.read_text().replace("sil_profile: sil.yaml", f"sil_profile: {CONFIG.parent / 'sil.yaml'}")
    path = tmp_path / "tvsd.yaml"
    path.write_text(text.split("\nidentify:")[0] + "\nidentify:\n" + section)
    return path


@pytest.mark.parametrize(
    "section,expect",
    [
        ("  prbs_v: 9\n", "identify.prbs_v: must be at most 6 V"),
        ("  kinds: [steps, chirp]\n", "identify.kinds[1]: expected one of steps, multisine, prbs"),
        ("  seconds: 200\n", "identify.seconds: must be at most max_seconds (120 s)"),
        (
            "  step_rps: 2\n",
            "identify.step_rps: the speed excitation (step_rps + multisine_rps of the kinds on) reaches 2.2",
        ),
        ("  multisine_max_hz: 200\n", "identify.multisine_max_hz: must be at most 100 Hz"),
        ("  prbs_clock_s: 0.0001\n", "identify.prbs_clock_s: must be at least 0.0004 s"),
        ("  prbs_v: 6.5\n", "identify.prbs_v: must be at most 6 V"),
        (
            "  min_rps: 59.5\n",
            "identify.min_rps: 59.5 rev/s plus the excitation (0.7) exceeds daemon.max_rps",
        ),
        ("  sekonds: 5\n", "identify.sekonds: unknown key; did you mean 'seconds'?"),
    ],
)
def test_a_bad_identify_section_names_its_line(tmp_path, section, expect):
    path = _config_with(tmp_path, section)
    line = len(path.read_text().splitlines())  # the key is the file's last line
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert f"{path}:{line}: {expect}" in str(err.value)


def test_prbs_beyond_half_the_drive_is_refused(tmp_path):
    """Half the drive's ±12 V left for the law: 6 V is the bound, named with the drive's limit."""
    path = _config_with(tmp_path, "  prbs_v: 5\n")
    load_config(path)  # 5 V < 6 V: fine
    text = path.read_text().replace("u_max_v: 12.0", "u_max_v: 8.0")
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"identify.prbs_v: 5 V is more than half of drive.u_max_v \(8 V\)"):
        load_config(path)


def test_settings_made_in_code_obey_the_same_rules():
    with pytest.raises(UsageError, match="kinds: unknown excitation 'chirp'"):
        IdentifySettings(kinds=("chirp",))
    with pytest.raises(UsageError, match="seconds: must be at least 1 s"):
        IdentifySettings(seconds=0.5)


# --- the table ---------------------------------------------------------------------------------------
def test_the_table_is_bounded_and_holds_each_kind():
    """Default settings: the speed excitation within ±max_delta_rps; steps at ±step_rps and 0, each
    held step_hold_s, both directions; the PRBS at ±prbs_v with bit time prbs_clock_s and about as
    many +1 as −1 bits; the multisine's power inside [min_hz, max_hz] (99 %); seed-reproducible."""
    s = IdentifySettings()
    ex = build(s)
    rate = s.table_rate_hz
    assert len(ex.d_rps) == round(s.seconds * rate) and ex.period_s == 1 / rate
    assert np.max(np.abs(ex.d_rps)) <= s.max_delta_rps
    steps = build(IdentifySettings(kinds=("steps",)))
    levels = set(np.unique(steps.d_rps))
    assert levels <= {-s.step_rps, 0.0, s.step_rps} and len(levels) == 3
    changes = np.flatnonzero(np.diff(steps.d_rps)) + 1
    assert np.all(np.diff(changes) % round(s.step_hold_s * rate) == 0)
    prbs = build(IdentifySettings(kinds=("prbs",)))
    assert set(np.unique(prbs.d_volts)) == {-s.prbs_v, s.prbs_v}
    edges = np.flatnonzero(np.diff(prbs.d_volts)) + 1
    assert np.all(edges % round(s.prbs_clock_s * rate) == 0)
    assert abs(np.mean(prbs.d_volts)) < 0.05 * s.prbs_v
    ms = build(IdentifySettings(kinds=("multisine",)))
    assert np.max(np.abs(ms.d_rps)) == pytest.approx(s.multisine_rps, rel=1e-9)
    spec = np.abs(np.fft.rfft(ms.d_rps)) ** 2
    f = np.fft.rfftfreq(len(ms.d_rps), ex.period_s)
    band = (f >= 0.5 * s.multisine_min_hz) & (f <= 1.5 * s.multisine_max_hz)
    assert spec[band].sum() > 0.99 * spec.sum()
    again = build(s)
    assert np.array_equal(again.d_rps, ex.d_rps) and np.array_equal(again.d_volts, ex.d_volts)
    assert not np.array_equal(build(IdentifySettings(seed=2)).d_volts, ex.d_volts)



def test_a_reversal_is_asked_for_bounded_centred_and_refused_when_it_does_not_fit():
    """Not in the default kinds (it turns the aperture backwards). Asked for: one segment, centred,
    where the offset takes the setpoint to −reversal_rps (the ramp down at scan_accel_rps2 plus the
    hold; the ramp back follows inside the run); without a setpoint, or too long for the run, a
    UsageError that says what to change."""
    assert "reversal" not in IdentifySettings().kinds
    s = IdentifySettings(kinds=("reversal",), seconds=20.0, reversal_rps=2.0, reversal_hold_s=2.0)
    ex = build(s, -10.0, 10.0)  # the magnitude counts: the daemon signs the table
    on = np.flatnonzero(ex.d_rps)
    assert set(np.unique(ex.d_rps)) == {0.0, -12.0} and np.all(np.diff(on) == 1)
    ramp = 12.0 / 10.0
    assert len(on) * ex.period_s == pytest.approx(ramp + 2.0, abs=2e-3)
    start = on[0] * ex.period_s
    assert start == pytest.approx(0.5 * (20.0 - (2 * ramp + 2.0)), abs=2e-3)
    assert not np.any(ex.d_volts)
    with pytest.raises(UsageError, match="needs the speed setpoint"):
        build(s)
    with pytest.raises(UsageError, match=r"takes 14.8 s; the run is 10 s: give --seconds 16 or more"):
        build(IdentifySettings(kinds=("reversal",), seconds=10.0, reversal_hold_s=10.0), 10.0, 5.0)
    with pytest.raises(UsageError, match="reversal_rps: must be at most 10 rev/s"):
        IdentifySettings(reversal_rps=11.0)

# --- the control thread plays it ---------------------------------------------------------------------
def test_the_loop_plays_the_table_at_its_own_tick_times(setup: Setup) -> None:
    """SIL runner scanning at 15 rev/s: a 0.4 s table of speed steps (±0.5 rev/s) and a ±1 V PRBS.
    For every tick, the row due at its wake time is the one it used: the speed reference ramps
    toward 15 + d_rps of that row, and the command is the law's output plus d_volts (clipped at the
    drive), to 1e-12. Ticks before t0 and after the table play nothing; the table switches off."""
    r = Runner(setup, excitation_rows=1000)
    r.scan(15.0)
    r.start()
    try:
        wait_for(lambda: r.ticks, 30.0, "3000 ticks", ok=lambda n: n > 3000)
        rows = 400
        d_rps = np.repeat([0.5, -0.5, 0.0, 0.5], rows // 4)
        d_volts = np.repeat(np.where(np.random.default_rng(1).random(rows // 4) > 0.5, 1.0, -1.0), 4)
        t0_ns = r.set_excitation(d_rps, d_volts, 1e-3)
        assert r.excitation_active
        wait_for(lambda: r.excitation_active, 30.0, "the table to end", ok=lambda on: not on)
        end = r.ticks
        wait_for(lambda: r.ticks, 30.0, "ticks after the table", ok=lambda n: n > end + 100)
    finally:
        r.stop(5.0)
    rec = r.recent_ticks()
    wake_ns = r.start_ns + np.round(rec["t"] * 1e9).astype(np.int64)
    row = np.floor_divide(wake_ns - t0_ns, 1_000_000)
    played = (row >= 0) & (row < rows)
    assert played.sum() > 0, "no tick inside the table's time"
    p = setup.plant
    g = setup.gains.as_tuple()
    accel = 2 * math.pi * setup.scan_accel_rps2
    # ticks within 1 µs of a row edge: the float time stamp cannot say which row (skipped)
    clear = np.abs((wake_ns - t0_ns) % 1_000_000) > 1000
    checked = 0
    for k in range(1, len(rec)):
        cur, prev = rec[k], rec[k - 1]
        if not clear[k] or row[k] < -1 or row[k] > rows + 1:
            continue
        on = bool(played[k])
        dr = d_rps[row[k]] if on else 0.0
        dv = d_volts[row[k]] if on else 0.0
        dt = cur["dt"]
        target = 2 * math.pi * (15.0 + dr)
        ramp = scanning.ramp_toward.py_func(prev["omega_ref"], target, accel * dt)
        assert cur["omega_ref"] == pytest.approx(ramp, abs=1e-9), f"tick {k}, row {row[k]}"
        alpha = (cur["omega_ref"] - prev["omega_ref"]) / dt
        u_ff = scanning.feedforward.py_func(
            cur["omega_ref"], alpha, p[P.P_J], p[P.P_KV] + p[P.P_S2], p[P.P_KM], p[P.P_KB],
            p[P.P_R], p[P.P_KU], p[P.P_TC], p[P.P_TS], p[P.P_V0],
        )  # fmt: skip
        lim = max(setup.u_max - abs(u_ff), 0.0)
        law = _law(cur["phi_ref"] - cur["phi"], cur["omega_ref"] - cur["omega"], g, lim) + u_ff
        expect = max(-setup.u_max, min(setup.u_max, law + dv))
        assert cur["u"] == pytest.approx(expect, abs=1e-12), f"tick {k}, row {row[k]}"
        checked += 1
    assert checked >= played.sum() // 2  # however late the machine woke the loop


def test_a_fault_or_a_mode_change_ends_the_excitation(setup: Setup) -> None:
    """The loop plays the table only while scanning without a fault: an overrun latch (the loop's
    safe state) clears it at once and the command is 0; so does going idle."""
    r = Runner(setup, excitation_rows=100_000)
    r.scan(10.0)
    r.start()
    try:
        wait_for(lambda: r.ticks, 30.0, "1000 ticks", ok=lambda n: n > 1000)
        r.set_excitation(np.full(100_000, 0.5), np.full(100_000, 0.5), 1e-3)  # 100 s
        wait_for(
            lambda: r.recent_ticks(1)["omega_ref"][0], 30.0, "the step", ok=lambda w: w > 2 * math.pi * 10.01
        )
        r.inject_overrun(3.0)
        wait_for(lambda: r.fault, 30.0, "the overrun latch")
        r.inject_overrun(0)
        wait_for(lambda: r.excitation_active, 5.0, "the excitation off", ok=lambda on: not on)
        assert r.command == 0.0
        r.clear_fault()
        r.set_excitation(np.full(100_000, 0.5), np.full(100_000, 0.5), 1e-3)
        now = r.ticks
        wait_for(lambda: r.ticks, 30.0, "ticks", ok=lambda n: n > now + 100)
        assert r.excitation_active
        r.idle()
        wait_for(lambda: r.excitation_active, 5.0, "the excitation off when idle", ok=lambda on: not on)
        with pytest.raises(ValueError, match=r"the runner holds 1 \.\. 100000"):
            r.set_excitation(np.zeros(100_001), np.zeros(100_001), 1e-3)
    finally:
        r.stop(5.0)


def test_playing_the_table_allocates_nothing(setup: Setup) -> None:
    """NRT allocation count flat while the loop plays an excitation (SIL, scanning): the table is
    preallocated and read in place."""
    from numba.core.runtime import _nrt_python as nrt_stats  # type: ignore[attr-defined]
    from numba.core.runtime import rtsys

    nrt_stats.memsys_enable_stats()
    try:
        r = Runner(setup, excitation_rows=20_000)
        r.scan(10.0)
        counts = []
        for n in (200, 5200):
            r.set_excitation(np.full(20_000, 0.3), np.full(20_000, 0.5), 1e-3)
            a = rtsys.get_allocation_stats().alloc
            r.start(max_ticks=n)
            r.join(60.0)
            assert r.excitation_active, "the table was still playing"
            counts.append(rtsys.get_allocation_stats().alloc - a)
    finally:
        nrt_stats.memsys_disable_stats()
    assert (counts[1] - counts[0]) / 5000 == 0.0


# --- the daemon's identify run, on a SIL runner and a real recording ---------------------------------
class _Host:
    """The parts of tvsd.daemon.app.Daemon an IdentifyRun uses, around a SIL runner (the plant in
    the loop) and a real SessionRecording; tests/test_identify_daemon.py runs the real daemon."""

    def __init__(self, runner: Runner, data_dir: Path) -> None:
        from tvsd.daemon.state import DaemonState

        self.runner, self.cfg, self.data_dir = runner, load_config(), data_dir
        self.state = DaemonState.SPINNING
        self.target_rps = 15.0
        self.recording = None
        self.identification = None
        self.marks: list[tuple[str, dict]] = []

    @property
    def measured_rps(self) -> float:
        return float(np.mean(self.runner.recent_ticks(100)["omega"])) / (2 * math.pi)

    def start_recording(self) -> Path:
        from tvsd.daemon.session_recording import SessionRecording

        path = self.data_dir / f"rec-{len(list(self.data_dir.glob('rec-*')))}"
        self.recording = SessionRecording(path, "", from_tick=self.runner.ticks)
        return path

    def mark(self, event: str, **data: object) -> None:
        self.marks.append((event, data))
        if self.recording is not None:
            self.recording.mark(event, **data)

    async def stop_recording(self) -> Path | None:
        rec, self.recording = self.recording, None
        if rec is None:
            return None
        rec.close()
        return rec.path

    async def drain(self) -> None:
        while True:
            await asyncio.sleep(0.02)
            if self.recording is not None:
                self.recording.drain(self.runner)


def _run_identify(host: _Host, settings: IdentifySettings, during=None) -> dict:
    from tvsd.daemon.identify import IdentifyRun

    async def main() -> dict:
        drain = asyncio.create_task(host.drain())
        run = IdentifyRun(host, settings)  # type: ignore[arg-type]
        run.check()
        host.identification = run  # type: ignore[assignment]
        run.start()
        if during is not None:
            await during(host, run)
        while not run.finished:
            await asyncio.sleep(0.05)
        drain.cancel()
        return run.to_json()

    return asyncio.run(main())


def _rps(r: Runner) -> float:
    ticks = r.recent_ticks(100)
    return float(np.mean(ticks["omega"])) / (2 * math.pi) if len(ticks) else 0.0


def _spinning(setup: Setup, rps: float) -> Runner:
    r = Runner(setup, excitation_rows=20_000)
    r.scan(rps)
    r.start()
    wait_for(lambda: _rps(r), 60.0, "spin-up", ok=lambda w: abs(w - rps) < 0.5)
    return r


def _ramped(d_rps: np.ndarray, period_s: float, accel_rps2: float) -> np.ndarray:
    """The table's speed offsets as the scanning ramp passes them (rate-limited)."""
    out = np.empty(len(d_rps))
    level = 0.0
    for k, target in enumerate(d_rps):
        level += min(max(target - level, -accel_rps2 * period_s), accel_rps2 * period_s)
        out[k] = level
    return out


def test_an_identify_run_records_its_table_and_ends_done(setup: Setup, tmp_path: Path) -> None:
    """A 3 s run on the SIL runner at 15 rev/s: done; the recording has the table (channel
    `excitation`), the reference that followed it, and the marks; the recording it opened is closed."""
    from tvsd.recording.reader import open_recording

    r = _spinning(setup, 15.0)
    host = _Host(r, tmp_path)
    try:
        res = _run_identify(host, IdentifySettings(seconds=3.0, step_hold_s=0.5))
    finally:
        r.stop(5.0)
    assert res["outcome"] == "done" and res["state"] == "done", res
    assert host.recording is None, "identify closes the recording it opened"
    rec = open_recording(Path(res["recording"]))
    exc, ref = rec.channels["excitation"], rec.channels["reference"]
    assert len(exc) == 3000 and exc["t"][0] == pytest.approx(res["t0_s"])
    played = (ref["t"] >= exc["t"][0]) & (ref["t"] <= exc["t"][-1])
    seen = ref["omega_ref"][played] / (2 * math.pi) - 15.0
    assert np.corrcoef(seen, np.interp(ref["t"][played], exc["t"], exc["d_rps"]))[0, 1] > 0.9
    assert [m["event"] for m in rec.marks if m["event"].startswith("identify")] == [
        "identify_start",
        "identify_end",
    ]


def test_an_identify_run_aborts_on_a_fault_and_refuses_what_it_must(setup: Setup, tmp_path: Path) -> None:
    """A loop fault (overrun latch) during the run: aborted, the excitation off, the reason named.
    Refused with −32002 too slow for the swing, not spinning, or still ramping."""
    from tvsd.daemon.identify import IdentifyRun
    from tvsd.daemon.rpc import STATE_ERROR, RpcError
    from tvsd.daemon.state import DaemonState

    r = _spinning(setup, 15.0)
    host = _Host(r, tmp_path)

    async def overrun(h: _Host, run) -> None:
        await asyncio.sleep(0.5)
        h.runner.inject_overrun(3.0)

    try:
        res = _run_identify(host, IdentifySettings(seconds=20.0), during=overrun)
        assert not r.excitation_active
        r.inject_overrun(0)
    finally:
        r.stop(5.0)
    assert res["outcome"] == "aborted" and "control thread fault (OVERRUN)" in res["reason"], res
    for state, target, why in (
        (DaemonState.IDLE, 15.0, "set a speed first"),
        (DaemonState.SPINNING, 5.5, "spin to at least 5.7 rev/s"),
        (DaemonState.SPINNING, 30.0, "not yet at its setpoint 30"),
    ):
        host.state, host.target_rps, host.identification = state, target, None
        with pytest.raises(RpcError, match=why) as err:
            IdentifyRun(host, IdentifySettings()).check()  # type: ignore[arg-type]
        assert err.value.code == STATE_ERROR


def test_draining_while_the_loop_ticks_neither_repeats_nor_skips_a_tick(setup: Setup, tmp_path: Path) -> None:
    """The recording drains the loop's ticks while the loop runs on: rows are taken up to the count
    it read, not up to a later one. Before, a tick between the two reads repeated rows and skipped
    as many; the 1 ms bins then averaged unsorted rows (a loaded run recorded 51 rev/s at 20).
    Drained as fast as it can for 1 s of ticks: every 1 ms bin once, strictly increasing, and
    ω_ref of each bin within the ramp's reach of its neighbours."""
    from tvsd.daemon.session_recording import SessionRecording
    from tvsd.recording.reader import open_recording

    r = Runner(setup)
    r.scan(10.0)
    rec = SessionRecording(tmp_path / "rec", "", from_tick=0)
    r.start()
    try:
        while r.ticks < 10_000:
            rec.drain(r)
    finally:
        r.stop(5.0)
    rec.drain(r)
    rec.close()
    loop = open_recording(tmp_path / "rec").channels["loop"]
    ref = open_recording(tmp_path / "rec").channels["reference"]
    assert np.all(np.diff(loop["t"]) > 0), "a bin recorded twice"
    step = 2 * math.pi * setup.scan_accel_rps2 * (1e-3 + 0.05)  # a bin and one MAX_DT stall
    assert np.max(np.abs(np.diff(ref["omega_ref"]))) <= step
