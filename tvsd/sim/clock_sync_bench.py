"""`tvsctl bench --only mcu_sil`: the link's clock sync over the SIL, measured.

:func:`bench_clock_sync` runs 60 s of SIL (tvsd.sim.mcu_plant.McuPlant, the virtual MCU behind
its pty) at 10 × real time with the link's heartbeats going and reports how far the link's
ClockSync maps MCU ticks from the truth (the plant's pacing line). Owner of this measurement
only; the plant it drives is tvsd.sim.mcu_plant's.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Any

import numpy as np

from tvsd.sim.mcu_plant import McuPlant


def bench_clock_sync(seconds: float = 60.0, speed: float = 10.0, duty: float = 0.5) -> dict[str, Any]:
    """Clock-sync error after `seconds` of SIL: MCU ticks mapped to host time by the link's
    ClockSync (heartbeats every 20 ms of wall time) against the truth, the pacing line on which
    the plant keeps the manual clock (host = wall0 + sim/speed). Runs `speed` × real time."""
    return asyncio.run(_bench(seconds, speed, duty))


async def _bench(seconds: float, speed: float, duty: float) -> dict[str, Any]:
    from tvsd.config import load_config
    from tvsd.hw.mcu.events import FaultEvent
    from tvsd.hw.mcu.link import McuLink
    from tvsd.hw.mcu.settings import McuSettings

    cfg = load_config()
    errs: list[tuple[float, float]] = []  # (sim s, error s)
    faults: list[FaultEvent] = []
    with McuPlant(cfg, speed=speed, record=False) as plant:
        hz = plant.mcu.clock_hz
        async with McuLink(McuSettings(port=plant.mcu.port), on_fault=faults.append) as link:
            # the watchdog in MCU time: 0.5 s of wall time without a heartbeat
            link.send_config(watchdog_ms=min(65535, math.ceil(500 * speed)), state_div=10, max_on_ms=0)
            link.send_pwm(duty)
            while plant.mcu.pwm_duty == 0.0:
                await asyncio.sleep(0.001)
            wall0 = time.monotonic()
            plant.start()
            while plant.t < 0.05:  # until the paced clock runs
                await asyncio.sleep(0.001)
            link.restart_clock_sync()  # the round trips so far saw a held clock
            clock = link.clock
            assert clock is not None
            while (t := plant.t) < seconds:
                await asyncio.sleep(0.1)
                if clock.ready:
                    err = clock.to_host(round(t * hz)) - plant.pacing.truth_host(t, speed)
                    errs.append((t, err))
            await link.stop_heartbeat()  # no round trip may see the clock held once it stops
            plant.stop()
            wall = time.monotonic() - wall0
            t_end = plant.t
            final = clock.to_host(round(t_end * hz)) - plant.pacing.truth_host(t_end, speed)
            st = link.stats()
            fit = clock.fit_
    last = np.array([e for t, e in errs if t >= t_end - 10.0])
    p = plant.pacing
    rate_ppm = (1.0 / (fit.seconds_per_tick * hz * speed) - 1.0) * 1e6 if fit is not None else math.nan
    return {
        "mcu_sil_sim_s": round(t_end, 3),
        "mcu_sil_speed": speed,
        "mcu_sil_wall_s": round(wall, 2),
        "mcu_sil_sync_err_us": round(final * 1e6, 1),
        "mcu_sil_sync_err_rms_last10s_us": round(float(np.sqrt(np.mean(last**2))) * 1e6, 1)
        if len(last)
        else None,
        "mcu_sil_sync_err_max_last10s_us": round(float(np.abs(last).max()) * 1e6, 1) if len(last) else None,
        "mcu_sil_pacing_lag_mean_us": round(p.lag_sum_s / max(p.feeds, 1) / speed * 1e6, 1),
        "mcu_sil_rate_err_ppm": round(rate_ppm, 1),
        "mcu_sil_rtt_p50_us": round(st.rtt_p50_s * 1e6, 1),
        "mcu_sil_lost_frames": st.lost_frames,
        "mcu_sil_faults": [f"{f.name}@{f.host_time - wall0:.3f}s" for f in faults] or None,
    }
