"""SIL pulses for the daemon: the zero and optical sensors fire as the simulated mirror turns.

The control thread records the shaft angle at every tick; the zero sensor fires when the unwrapped
angle crosses 2πk, the optical one when it crosses 2πk + β of the lit target (the mirror meets the
reflected ray). Crossing times are interpolated between ticks and quantised to the MCU timer, as the
firmware's input capture would stamp them (62.5 ns: firmware/PROTOCOL.md).
"""

from __future__ import annotations

import math

import numpy as np

from tvsd.scan.pulses import OPTICAL, ZERO

TWO_PI = 2.0 * math.pi


class PulseSensors:
    """Turns (t, φ) batches into time-ordered (kind, ticks) pulses; remembers the last angle."""

    def __init__(self, beta_rad: float, tick_s: float) -> None:
        self.beta = beta_rad % TWO_PI
        self.tick_s = tick_s
        self._t: float | None = None
        self._phi = 0.0

    def feed(self, t: np.ndarray, phi: np.ndarray) -> list[tuple[int, int]]:
        if len(t) == 0:
            return []
        if self._t is None:
            self._t, self._phi = float(t[0]), float(phi[0])
        tt = np.concatenate([[self._t], t])
        pp = np.concatenate([[self._phi], phi])
        self._t, self._phi = float(t[-1]), float(phi[-1])
        events: list[tuple[float, int]] = []
        for kind, offset in ((ZERO, 0.0), (OPTICAL, self.beta)):
            # Revolution index of each sample relative to the sensor's angle: a change is a crossing.
            rev = np.floor((pp - offset) / TWO_PI)
            for i in np.nonzero(np.diff(rev) > 0)[0]:  # forward crossings only
                target = (rev[i + 1]) * TWO_PI + offset
                frac = (target - pp[i]) / (pp[i + 1] - pp[i])
                events.append((tt[i] + frac * (tt[i + 1] - tt[i]), kind))
        events.sort()
        return [(kind, round(when / self.tick_s)) for when, kind in events]
