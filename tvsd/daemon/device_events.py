"""The devices' events on the event loop's thread: pulses become points, IMU batches and states.

Pulses from the MCU become points as they arrive (`_on_pulse`), published with the optical
pulse's host time; IMU batches feed the compensated stream; an IMU lost or degraded is a fault
entry (scanning continues, points flagged no_imu) and switches the scan session.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from tvsd.daemon.commands import Commands
from tvsd.daemon.faults import FaultKind
from tvsd.daemon.state import DaemonState
from tvsd.hw.mcu.events import PulseEvent
from tvsd.scan.points import Point
from tvsd.scan.pulses import OPTICAL

S = DaemonState


class DeviceEvents(Commands):
    """Callbacks of the drive link and the IMU service (event-loop thread)."""

    def _on_pulse(self, ev: PulseEvent) -> None:
        if self.recording is not None:
            self.recording.pulse(ev.host_time, ev.mcu_ticks, ev.channel)
        if self.state != S.SCANNING or self.scan is None:
            return
        self._publish(self.scan.pulse(ev.channel, ev.mcu_ticks))
        if ev.channel == OPTICAL:
            self.points.optical_pulse()

    def _publish(self, points: list[Point]) -> None:
        for computed in points:
            # The optical pulse's host time: a client on this machine gets the latency from
            # pulse to point as time.monotonic() − t_mono on receipt.
            point = replace(computed, t_mono=self.drive.to_host(round(computed.t * self.drive.clock_hz)))
            self.points.published(point)
            if self.web is not None:
                self.web.point(point)
            record = point.to_json()
            self.rpc.publish("points", record)
            self.can.publish_point(record)
            if self.recording is not None:
                self.recording.point(point)

    def _on_imu_state(self, state: str, detail: str) -> None:
        self.mark("imu_state", state=state, detail=detail)
        if state in ("lost", "degraded"):
            self._fault(FaultKind.IMU, f"IMU {state}: {detail}", "scanning continues; points flagged no_imu")
        self._follow_compensation()  # compensated while the IMU is ok, flagged no_imu while it is not

    def _on_imu_batch(self, batch: Any) -> None:
        if self.web is not None:
            self.web.imu_batch(batch)
        if self.recording is not None:
            self.recording.imu_batch(batch.sensor, batch.k, batch.t, batch.accel, batch.gyro)
        if self.scan is not None and self.state == S.SCANNING:
            self._follow_compensation()  # the clock sync: ready, or lost its round trips
            self._publish(self.scan.imu_batch(batch))
