"""`tvsctl bench --only imu_sil`: the SIL I2C bus's service time per request, as the daemon meets it.

The SIL devices' process (tvsd.sim.sil_process: its plant paced at real time, the IMU twins
following the plant's disturbance) answers the daemon's own IMU reader (tvsd.hw.imu_reader, in
this process, over tvsd.hw.i2c_remote) for `seconds`, both with the soak's priorities when
`realtime` (SCHED_FIFO: the SIL process 30, its bus thread 45, the reader 50). Its bus thread
times every request (tvsd.sim.bus_timing.TimedBus: service mean / p99 / max, split into the
modelled 400 kHz bit time, the thread's own CPU and the waits) and exports it each second through
$TVSD_SIL_STALLS. The plant stands still (no daemon drives its motor here); the twins still
compute every sample from its disturbance (their rest limit set to 0). The figures include the
reader's bring-up (a few dozen short requests of ~2000).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from tvsd.config.load import load_config
from tvsd.hw.imu_reader import READER_PRIORITY, make_reader
from tvsd.sim.sil_devices import SilDevices
from tvsd.sim.sil_process import SilParams
from tvsd.sim.sil_watch import ENV_STALLS, EXPORT_S


def _report(path: Path, since: float, wait_s: float) -> dict[str, Any]:
    """The SIL process's latest report written after `since` (its export runs each EXPORT_S)."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            if path.stat().st_mtime >= since:
                got: dict[str, Any] = json.loads(path.read_text())
                return got
        except (OSError, ValueError):  # not there yet, or caught mid-replace
            pass
        if time.monotonic() > deadline:
            return {}
        time.sleep(0.1)


def _total(status: dict[str, dict[str, object]], key: str) -> int:
    return sum(int(str(s.get(key, 0))) for s in status.values())


def bench_sil_bus(seconds: float = 10.0, realtime: bool = True) -> dict[str, Any]:
    cfg = load_config()
    with tempfile.TemporaryDirectory(prefix="tvsd-i2c-bench-") as tmp:
        export = Path(tmp) / "sil.json"
        params = SilParams(cfg, 0.0, plant=True, still_below_rps=0.0)
        sil = SilDevices.spawn(params, realtime=realtime, env={ENV_STALLS: str(export)})
        try:
            sil.wait_ready()
            bus = sil.imu_bus()
            reader = make_reader(bus, cfg.imu)
            if realtime:
                reader.priority = READER_PRIORITY
            reader.start()
            time.sleep(seconds)
            reader.stop()
            status, rtt = reader.status(), bus.stats()
            ended = time.time()
            report = _report(export, ended, 3 * EXPORT_S).get("bus", {})
        finally:
            sil.close()
    samples, lost = _total(status, "samples"), _total(status, "lost")
    out: dict[str, Any] = {f"sil_bus_{k}": v for k, v in report.items() if k != "service_over_ms"}
    out.update(
        {
            "sil_bus_seconds": seconds,
            "sil_bus_realtime": realtime,
            "sil_bus_rtt_mean_ms": rtt["rtt_mean_ms"],
            "sil_bus_rtt_max_ms": rtt["rtt_max_ms"],
            "sil_bus_imu_lost_pct": round(100 * lost / max(samples + lost, 1), 3),
            "sil_bus_imu_overflows": _total(status, "overflows"),
            "sil_bus_load_avg_1min": round(os.getloadavg()[0], 1),
        }
    )
    return out
