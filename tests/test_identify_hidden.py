"""The README's identify → export → analyze loop on a SIL daemon whose plant hides an effect: the
doctor must name it from the daemon's own recording, through the command line as a user runs it.

The hidden effect is an imbalance of 2e-4 N·m at 25 rev/s (the SIL profile's `effects:`, which the
daemon's recording does not carry): ≈ 6× the matrix's base size for the config's plant (0.5·J),
where the closed-loop matrix names imbalance in every case from 3× (docs/measurements/doctor-closed.md,
"Closed loop"); offline
the same excitation named it on 2 of 2 seeds, with `none` on the two null runs. The export's u is
the PWM frames the daemon sent (held, 1 ms means): the law's own mean, written as u before, led
the applied voltage by a scattered 2-19 ms and the doctor named a delay, a clip, a resonance or
negative damping for it. The export's omega and phi are the MCU's encoder frames at their
sampling instants (channel `states`, tvsd/cli/export_states.py): the control thread's own
measurement, 3 ms late and standing still where frames arrived in a burst, made a `cogging` of
orders 13-20 (3 of 18 earlier exports, re-analysed) and most of a 3.5-3.8 ms `delay`. With it,
12 of 12 runs passed at load 8-14: imbalance 1.96-2.25e-4 (± 1.1-1.2e-5), cogging z <= 1.6, a
delay of 1.2 and 1.6 ms twice (the SIL chain's own, below); both null runs `none`
(docs/measurements/doctor-method.md, model doctor step 8). The doctor names every cause the data
support (tvsd.analysis.selection), and the imbalance must be among them.
The daemon runs with the fail-safe times widened (conftest.RELAXED_FAILSAFE), as every SIL daemon
test does, the MCU handshake and identify's speed check widened too, and --realtime: this test is about the
doctor's answer on a clean recording, not the fail-safe's timing (test_identify_daemon.py and
test_daemon.py test those). A recording that shows the daemon stalled is skipped, with the reason.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import RELAXED_FAILSAFE, daemon_config
from test_daemon import _daemon, spin_to, tvsctl, wait_status

from tvsd.recording.csvfile import read

HIDDEN = "imbalance:amplitude=2e-4,phase=0.5"
RPS = 25.0
ROOT = Path(__file__).resolve().parents[1]
MAX_GAPS = 50  # filled 1 ms stretches: docs/measurements/identify.md's run 0; --realtime runs at
# load 20: 9-22
# rms of ω − ω_ref over the export: 0.039-0.042 rev/s on three clean runs at load 15; one run
# whose gaps stayed under MAX_GAPS lost the reference (rms 0.54, p99 2.5 rev/s: the speed spread
# of the identify excitation doubled) and its imbalance statistic was 1.0 (z, own null; 12-29 on
# the clean runs): stalls, not what the doctor is judged on here
MAX_TRACKING_RPS = 0.2
ATTEMPTS = 3  # identify runs aborted because the speed strayed (a stalled daemon), then given up


@pytest.fixture
def hidden_daemon(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], Path, Path]]:
    sil = (ROOT / "config" / "sil.yaml").read_text()
    assert "\neffects: []" in sil, "config/sil.yaml's effects line changed: update the test"
    (tmp_path / "sil.yaml").write_text(sil.replace("\neffects: []", f'\neffects: ["{HIDDEN}"]'))
    changes = {
        **RELAXED_FAILSAFE,
        # the SIL devices' process answers the MCU handshake late on a loaded machine (the daemon
        # then stops at start-up: "stopping" before the first command)
        "  identify_timeout_ms: 500 ": "  identify_timeout_ms: 10000 ",
        # a stall of this non-realtime daemon lets the speed stray past 3 rev/s (4.85 seen at load
        # 20), which aborts the run (its safety check, tested in test_identify_daemon.py)
        "  abort_error_rps: 3.0 ": "  abort_error_rps: 10.0 ",
        "sil_profile: sil.yaml": f"sil_profile: {tmp_path / 'sil.yaml'}",
    }
    # --realtime, as `make run` and the scanner run it: at normal priority on a loaded machine the
    # daemon stalls, and a recording with stalls (filled gaps, speed excursions) is not what the
    # doctor is judged on here (run it alone, not beside another real-time test or soak).
    yield from _daemon(tmp_path, daemon_config(tmp_path, changes), realtime=True)


# Torques not hidden in the plant. A later cause is named at the decision's own false-alarm rate
# (tvsd.analysis.selection: α = 1 % per recording once every real cause is in the model), so one
# recording in a hundred names one of these by chance: CI saw a `resonance` at z 3.91 against its
# gate 3.85 as a second cause. A spurious cause on the first recording is therefore judged on a
# second, independent one: only a cause named on both fails (by chance α² = 1e-4; a doctor that
# names one on a share p of such recordings fails with p², 9 % at p = 30 %, every time at p = 1).
SPURIOUS = {"cogging", "resonance", "friction_asymmetry", "drift"}


@pytest.mark.slow
def test_identify_export_analyze_names_the_hidden_imbalance(hidden_daemon, tmp_path):
    _, sock, _ = hidden_daemon
    spin_to(sock, RPS, timeout=60)
    verdict, shown = _identify_and_analyze(sock, tmp_path / "identify.csv")
    named = {c["cause"]: c for c in verdict["causes"]}
    assert "imbalance" in named, shown
    # No other torque is hidden in the plant. The command's path (daemon → serial link → MCU →
    # H-bridge) is the SIL loop's own and may show as a `delay` (1.0-1.5 ms from a frame's
    # sending to the SIL plant, applied in its next 1 ms chunk; named 1.2 and 1.6 ms on 2 of 12
    # runs with omega from the frames, z -0.6-3.1 on the others).
    # No clip: the export's u shows every clip the drive makes (docs/measurements/doctor-method.md, step 8).
    if set(named) & SPURIOUS:
        try:
            again, shown_again = _identify_and_analyze(sock, tmp_path / "identify-2.csv")
        except pytest.skip.Exception as stalled:  # no second judgement: the first one stands
            pytest.fail(f"first: {shown} || second recording not judged: {stalled}")
        twice = set(named) & {c["cause"] for c in again["causes"]} & SPURIOUS
        assert not twice, f"first: {shown} || second: {shown_again}"
    if "delay" in named:
        assert 1e-3 < named["delay"]["effect"]["delay_s"] < 20e-3, shown
    # The amplitude within 4 of its own standard errors (the vibration's share, and J's), a miss
    # by chance ≈ 6e-5: on a 20 s export ±2.3e-5 N·m, so ±45 % (the factor 2 before was ±100 %/−50 %).
    imb = named["imbalance"]["effect"]
    assert abs(imb["amplitude"] - 2e-4) < 4 * imb["amplitude_se"], shown


def _identify_and_analyze(sock: Path, out: Path) -> tuple[dict, str]:
    """One identify run at the setpoint, exported to `out` and analysed: (verdict, its summary).
    Skips the test when the recording shows the daemon stalled."""
    run: dict = {}
    for _ in range(ATTEMPTS):
        # identify's own bound is 180 s; the subprocess's must be longer, or the test dies first
        proc = tvsctl(
            sock, "identify", "--seconds", "20", "--json", "--timeout", "180", check=False, timeout=240
        )
        run = json.loads(proc.stdout) if proc.stdout.strip() else {"refused": proc.stderr}
        if run.get("outcome") == "done":
            break
        # a refusal while the speed is off its setpoint, or a run aborted because it strayed (a
        # stall of this non-realtime daemon on a loaded machine): the safety checks did their job;
        # back at the setpoint, the run again. Anything else fails below.
        if not ("settles" in str(run.get("refused")) or "strayed" in str(run.get("reason"))):
            break
        wait_status(sock, lambda s: abs(s["rps"] - RPS) < 0.5, 60, f"{RPS} rev/s again", fault_ends=True)
    assert run.get("outcome") == "done", run
    cli = [sys.executable, "-m", "tvsd.cli.main"]
    exp = subprocess.run(
        [*cli, "export", run["recording"], "--csv", str(out)], capture_output=True, text=True, timeout=120
    )
    assert exp.returncode == 0, exp.stderr
    rec = read(out)
    meta = rec.meta
    tracking = float(np.sqrt(np.mean((rec.omega - rec.extra["omega_ref"]) ** 2))) / (2 * np.pi)
    if int(meta["gaps"]) > MAX_GAPS or int(meta["faults"]) > 0 or tracking > MAX_TRACKING_RPS:
        pytest.skip(
            f"the daemon stalled during the run ({meta['gaps']} gaps, {meta['faults']} faults in its "
            f"recording, speed off its reference by {tracking:.2f} rev/s rms): not the recording "
            "this test judges the doctor on; run it without CPU hogs"
        )
    header = next(line for line in out.read_text().splitlines() if not line.startswith("#"))
    assert {"omega_ref", "phi_ref", "u_exc", "omega_loop"} <= set(header.split(","))
    assert "encoder frames" in str(meta["omega_source"]), meta
    # u and omega are both means over each 1 ms bin: said so, the doctor's delay is measured
    # against that, not a sample unsure (undeclared, a delay under 2 ms was not named).
    assert meta["u_sampling"] == "mean", meta
    ana = subprocess.run(
        [*cli, "analyze", str(out), "--json", "--quiet"], capture_output=True, text=True, timeout=300
    )
    assert ana.returncode == 0, ana.stderr
    verdict = json.loads(ana.stdout)
    return verdict, _brief(verdict, meta, tracking)


def _brief(verdict: dict, meta: dict, tracking: float) -> str:
    """What a failure must show in one screen (pytest cuts a long dict's repr in the middle):
    each cause named and the leading candidates with their statistic, gate and effect, and the
    recording's own state."""

    def one(c: dict) -> str:
        eff = {k: v for k, v in (c.get("effect") or {}).items() if isinstance(v, (int, float))}
        return f"{c['cause']} z={c.get('score')!s:.6} gate={c.get('threshold')!s:.6} {eff}"

    named = "; ".join(one(c) for c in verdict["causes"])
    others = "; ".join(one(c) for c in verdict["candidates"][:5])
    return (
        f"named: {named} | candidates: {others} | recording: {meta['gaps']} gaps, "
        f"{meta.get('gap_samples', 0)} filled samples, tracking {tracking:.3f} rev/s rms"
    )
