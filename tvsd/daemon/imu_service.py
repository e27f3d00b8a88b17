"""The daemon's IMUs: one owner of the bus, the reader thread, loss detection and calibration.

`ImuService.for_daemon(cfg, backend, plant)` (or `ImuService(settings, backend, ...)`), backend
"hardware" (smbus2 on /dev/i2c-N), "sil" (the register-level twins, tvsd.sim.mpu6050, on the
real-time clock with the bus's bit time charged, moved by the running drive plant through
tvsd.sim.imu_motion.PlantMotion, at rest without one) or "off". `await start()` opens the bus
(DeviceError if it cannot) and starts the reader thread (tvsd.hw.imu_reader); the batches come to
the event loop's thread and go to `on_batch(batch)`. `await stop()` stops the thread and closes
the bus.

State ("off", "starting", "ok", "degraded", "lost"), per sensor and overall (the worst):
- "degraded": the reader's own verdict (two bus failures in a row; it retries with back-off);
- "lost": no sample delivered for more than `lost_after_s` = 5 × poll interval + imu.lost_margin_s (0.2 s at
  the default 20 ms), or none since start after bring-up (0.13 s) + that bound. Why 5 polls: in
  normal running every poll (20 ms) delivers; one failed transfer costs a 5–10 ms back-off and a
  poll; five polls without data is past the FIFO's 85 ms at 1 kHz, so samples have surely been
  dropped (the reader's own reset check uses the same 5 polls). The 0.1 s margin covers host
  wake-ups late by tens of ms. The time of the last delivery is taken on the reader thread, so a
  busy event loop does not look like a lost sensor.
The state is checked every `lost_after_s` / 4; `on_state(state, detail)` is called on the loop's
thread at every change of the overall state (the first: "starting" at start; none at stop).
`healthy` is True in state "ok" only.

`await calibrate(seconds)`: the raw samples of the running reader over `seconds`, the existing
motion check and bias (tvsd.hw.imu_calibration) off the loop's thread, the file written
(settings.calibration_file), and the new gyro bias applied to the running readers. Errors:
UsageError (bad seconds), CalibrationRefused (moving, or a calibration already running),
DeviceError (no IMU, too few samples, file not writable).

`inject("loss" | "restore", sensor=None)`: SIL only — the twin bus stops answering (a disconnect
fault: the sensors keep sampling, the bus NACKs) or answers again.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from tvsd.errors import DataFileError, DeviceError, UsageError
from tvsd.hw import imu_calibration as cal
from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.i2c_bus import open_bus
from tvsd.hw.imu_clock import Clock, MonotonicClock
from tvsd.hw.imu_reader import HEAP_RESERVE_BYTES, READER_PRIORITY, ImuReader
from tvsd.hw.imu_sensor_reader import ImuBatch, SensorReader
from tvsd.hw.imu_settings import SA_AXES, ImuSettings, to_si
from tvsd.hw.loop_handoff import LoopHandoff
from tvsd.hw.mpu6050 import Mpu6050, SMBusLike
from tvsd.sim.imu_motion import LivePlant, MotionSource

if TYPE_CHECKING:
    from tvsd.config import Config

log = logging.getLogger(__name__)

NAMES = ("pl", "sa")
BACKENDS = ("hardware", "sil", "off")
STILL_RPS = 0.05  # SIL: the twins feel the plant's vibration only while the shaft turns faster
STATES = ("off", "ok", "starting", "degraded", "lost")  # by severity: the overall is the worst
LOST_POLLS = 5
INJECT_KINDS = ("loss", "restore")
ENV_STALLS = "TVSD_DAEMON_STALLS"  # a file: the daemon's stall watch (tvsd.sim.sil_watch) writes there
SNAPSHOT_S = 0.2  # how often the reader thread refreshes a sensor's fitted rate and loss count

OnBatch = Callable[[ImuBatch], None]
OnState = Callable[[str, str], None]


def _fifo_here() -> bool:
    """Whether the calling thread runs SCHED_FIFO (the daemon's event loop under --realtime)."""
    try:
        return os.sched_getscheduler(0) == os.SCHED_FIFO
    except (OSError, AttributeError):
        return False


def _json_float(x: object) -> object:
    """inf / nan (a rate not fitted yet) as None: the status must be plain JSON."""
    return None if isinstance(x, float) and not math.isfinite(x) else x


class ImuService:
    """Owner of the daemon's two MPU6050s (one bus, one reader thread)."""

    def __init__(
        self,
        settings: ImuSettings,
        backend: str,
        *,
        motions: Mapping[str, MotionSource] | None = None,
        plant: LivePlant | None = None,
        on_batch: OnBatch | None = None,
        on_state: OnState | None = None,
        bus_timing: bool = True,
        seed: int = 0,
        open_bus: Callable[[ImuSettings], SMBusLike] | None = None,
    ) -> None:
        """SIL: `plant`, the SIL devices' process (tvsd.sim.sil_devices.SilDevices: its twins,
        over its bus, tvsd.hw.i2c_remote), or a running (paced) tvsd.sim.mcu_plant.McuPlant in
        this process, moving twins here (tvsd.sim.imu_motion.plant_pair on the SA axis, on its
        PlantClock); else `motions` per sensor ("pl", "sa"); else at rest. `bus_timing`: SIL
        charges each transfer's bit time at 400 kHz, as the real bus. `open_bus`: the hardware
        opener (tests)."""
        if backend not in BACKENDS:
            raise UsageError(f"IMU backend {backend!r}: one of {', '.join(BACKENDS)}")
        self.settings, self.backend = settings, backend
        self.motions, self.plant = motions, plant
        self.on_batch, self.on_state = on_batch, on_state
        self.bus_timing, self.seed = bus_timing, seed
        self._open_bus = open_bus
        self.lost_after_s = LOST_POLLS * settings.poll_interval_s + settings.lost_margin_s
        self.clock: Clock = MonotonicClock()
        self.bus: SMBusLike | None = None
        self.reader: ImuReader | None = None
        self.devices: dict[str, Any] = {}  # SIL: the twins (tvsd.sim.mpu6050.SimMpu6050)
        self._sensors: dict[str, SensorReader] = {}
        self._watch: asyncio.Task[None] | None = None
        self._t_start = math.nan
        self._last_data: dict[str, float] = {}  # reader thread's clock at the last delivery
        self._snap: dict[str, dict[str, object]] = {}  # SensorReader.status(), on the reader thread
        self._snap_t: dict[str, float] = {}
        self._batches: dict[str, int] = dict.fromkeys(NAMES, 0)
        self._state, self._detail = "off", ""
        self._collect: dict[str, list[np.ndarray]] | None = None  # raw frames while calibrating
        self._calibration: dict[str, object] = {"file": str(settings.calibration_file), "applied": False}
        self._injected: list[Any] = []
        self._handoff: LoopHandoff[ImuBatch] = LoopHandoff(self._deliver, "IMU batch")  # reader → loop
        self._stalls: Any = None

    @classmethod
    def for_daemon(cls, cfg: Config, backend: str, plant: Any = None) -> ImuService:
        """The daemon's IMUs from its config: the `imu:` section, and in SIL the twins moved by
        the running drive plant (a tvsd.sim.mcu_plant.McuPlant, PlantMotion on the configured SA
        axis, PL coupled at 0.3), or at rest without one. Set on_batch / on_state, then start()."""
        return cls(cfg.imu, backend, plant=plant, seed=cfg.sil_or_default.seed)

    # --- life cycle --------------------------------------------------------------------------------
    async def start(self) -> None:
        """Open the bus and start the reader thread; DeviceError if the bus cannot be opened.
        Call from the event loop that should receive the batches."""
        if self.backend == "off" or self.reader is not None:
            return
        self._handoff.loop = asyncio.get_running_loop()
        bus = await asyncio.to_thread(self._open)  # file and device opens: off the loop
        try:
            bias = await asyncio.to_thread(self._load_calibration)
        except BaseException:
            bus.close()
            raise
        self._sensors = {
            n: SensorReader(Mpu6050(bus, n, self.settings, self.clock.sleep), self.clock, bias.get(n))
            for n in NAMES
        }
        self.bus = bus
        self.reader = ImuReader(list(self._sensors.values()), self.clock, self._sink, self._polled)
        if _fifo_here():  # tvsd --realtime: the loop's thread is SCHED_FIFO; the reader above it
            self.reader.priority = READER_PRIORITY
        self.reader.heap_reserve = HEAP_RESERVE_BYTES  # taken only after the daemon's heap.tune()
        self._t_start = self.clock.now()
        self._last_data.clear()
        self._snap.clear()
        self._snap_t.clear()
        self._handoff.clear()
        self.reader.start()
        # its arena's reserve (tvsd.hw.heap) comes before its first poll: "no samples since
        # start" counts from the polls' start, not from the reserve's page faults
        await asyncio.to_thread(self.reader.started.wait, 5.0)
        self._t_start = self.clock.now()
        if os.environ.get(ENV_STALLS, "").strip():  # a soak's measurement: the daemon's own stalls
            from tvsd.sim.sil_watch import StallWatch

            self._stalls = StallWatch(export_to=os.environ[ENV_STALLS].strip())
            self._stalls.start(_fifo_here(), READER_PRIORITY + 1)
        self._set_state("starting", "bringing the sensors up")
        self._watch = asyncio.create_task(self._watchdog(), name="imu-watchdog")

    def _open(self) -> SMBusLike:
        if self.backend == "hardware":
            if self._open_bus is not None:
                return self._open_bus(self.settings)
            return open_bus(self.settings)
        from tvsd.sim.imu_motion import PlantClock, SyntheticParams, plant_pair, synthetic_pair
        from tvsd.sim.mpu6050 import sil_pair

        remote = getattr(self.plant, "imu_bus", None)
        if remote is not None:  # the twins in the SIL devices' process, across its boundary
            bus: SMBusLike = remote()
            return bus
        twin_clock: Clock = self.clock
        motions = self.motions
        if self.plant is not None:
            # at rest below the calibration's own limit (tvsd.daemon.api: 0.05 rev/s)
            motions = plant_pair(
                self.plant, axis=SA_AXES[self.settings.sa_axis], still_below_rps=STILL_RPS
            )
            twin_clock = PlantClock(self.plant)
        elif motions is None:  # at rest: gravity, the twins' noise and biases
            motions = synthetic_pair(SyntheticParams(rps=0.0, imbalance_rad_s2=0.0, vibration_std_rad_s2=0.0))
        sim_bus, self.devices = sil_pair(
            self.settings, twin_clock, motions, bus_hz=400e3 if self.bus_timing else None, seed=self.seed
        )
        return sim_bus

    def _load_calibration(self) -> dict[str, np.ndarray]:
        """The file's gyro biases; none (a warning, in status) if absent or damaged: the IMU
        still runs, uncalibrated, and `calibrate` writes a good file."""
        path = self.settings.calibration_file
        try:
            calib = cal.load_or_none(path)
        except (DataFileError, OSError) as exc:
            log.warning("IMU calibration not applied: %s", exc)
            self._calibration = {"file": str(path), "applied": False, "error": str(exc)}
            return {}
        if calib is None:
            log.warning("no IMU calibration at %s: gyro bias not removed", path)
            self._calibration = {"file": str(path), "applied": False, "error": "no file: calibrate at rest"}
            return {}
        self._calibration = {"file": str(path), "applied": True}
        return {n: np.asarray(c.gyro_bias_rad_s, dtype=float) for n, c in calib.items() if n in NAMES}

    async def stop(self) -> None:
        """Stop the reader thread (joined off the loop's thread) and close the bus."""
        if self._watch is not None:
            self._watch.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watch
            self._watch = None
        if self._stalls is not None:
            self._stalls.stop()
            self._stalls = None
        reader, bus = self.reader, self.bus
        self.reader, self.bus = None, None
        if reader is not None:
            await asyncio.to_thread(reader.stop)
        if bus is not None:
            with contextlib.suppress(OSError):
                bus.close()
        self._state, self._detail = "off", ""

    # --- batches: reader thread → loop thread ----------------------------------------------------
    def _sink(self, batch: ImuBatch) -> None:
        """On the reader thread: note the delivery, queue the batch for the loop. Never raises
        (ImuReader would lose its thread). A poll delivers both sensors' batches: one wake-up of
        the loop for them (tvsd.hw.loop_handoff)."""
        self._last_data[batch.sensor] = self.clock.now()
        self._handoff.put(batch)

    def _polled(self, sensor: SensorReader) -> None:
        """On the reader thread after each sensor's turn, data or not: refresh its status snapshot
        (the fitted rate and `lost`, which grows while a sensor is gone) every SNAPSHOT_S.
        Never raises."""
        now = self.clock.now()
        if now - self._snap_t.get(sensor.name, -math.inf) >= SNAPSHOT_S:
            with contextlib.suppress(Exception):  # the fit's rate and loss estimate: this thread's
                self._snap[sensor.name] = sensor.status()
                self._snap_t[sensor.name] = now

    def _deliver(self, batch: ImuBatch) -> None:
        self._batches[batch.sensor] = self._batches.get(batch.sensor, 0) + 1
        if self._collect is not None and batch.sensor in self._collect:
            self._collect[batch.sensor].append(batch.raw)
        if self.on_batch is not None:
            try:
                self.on_batch(batch)
            except Exception:  # the daemon's bug must not stop the IMU's deliveries
                log.exception("IMU on_batch callback failed")

    # --- state ------------------------------------------------------------------------------------
    @property
    def state(self) -> str:
        return self._state

    @property
    def healthy(self) -> bool:
        return self._state == "ok"

    def _sensor_state(self, name: str, reader_state: str, last_error: str, now: float) -> tuple[str, str]:
        last = self._last_data.get(name)
        bring_up = reg.RESET_S + reg.GYRO_STARTUP_S
        why = f" (last error: {last_error})" if last_error else ""
        if last is None:
            if now - self._t_start > bring_up + self.lost_after_s:
                return "lost", f"{name} IMU: no samples since start{why}"
            if reader_state == "degraded":
                return "degraded", last_error or f"{name} IMU: bus errors"
            return "starting", ""
        age = now - last
        if age > self.lost_after_s:
            return "lost", f"{name} IMU: no samples for {age:.2f} s{why}"
        if reader_state == "degraded":
            return "degraded", last_error or f"{name} IMU: bus errors"
        return "ok", ""

    def _evaluate(self) -> tuple[str, str, dict[str, dict[str, object]]]:
        if self.reader is None:
            return "off", "", {}
        now = self.clock.now()
        per: dict[str, dict[str, object]] = {}
        worst, details = "ok", []
        for name, sensor in self._sensors.items():
            # Not ImuReader.status(): it waits for the reader's lock, held over a whole poll (ms of
            # bus time, more on a stalled bus). The fitted rate and the loss estimate come from
            # the reader thread's latest snapshot; the plain counters are read as they are.
            st = {"rate_hz": None, "rate_sigma_hz": None, "lost": None, **self._snap.get(name, {})}
            st.update(
                state=sensor.state,
                chip=sensor.chip,
                samples=sensor.samples,
                errors=sensor.errors,
                overflows=sensor.overflows,
                resyncs=sensor.resyncs,
                restarts=sensor.restarts,
                last_error=sensor.last_error,
            )
            per[name] = st
            state, detail = self._sensor_state(name, str(st["state"]), str(st["last_error"]), now)
            st["reader_state"], st["state"] = st["state"], state
            last = self._last_data.get(name)
            st["age_s"] = None if last is None else round(now - last, 4)
            st["batches"] = self._batches.get(name, 0)
            if STATES.index(state) > STATES.index(worst):
                worst = state
            if detail:
                details.append(detail)
        return worst, "; ".join(details), per

    def _set_state(self, state: str, detail: str) -> None:
        changed = state != self._state
        self._state, self._detail = state, detail
        if not changed:
            return
        (log.info if state in ("ok", "starting") else log.warning)("IMU %s: %s", state, detail or "-")
        if self.on_state is not None:
            try:
                self.on_state(state, detail)
            except Exception:
                log.exception("IMU on_state callback failed")

    async def _watchdog(self) -> None:
        period = self.lost_after_s / 4
        while True:
            await asyncio.sleep(period)
            state, detail, _ = self._evaluate()
            self._set_state(state, detail)

    def status(self) -> dict[str, object]:
        """{"source", "state", "detail", "healthy", "lost_after_s", "calibration", "sensors":
        {name: reader counters (samples, lost, errors, overflows, resyncs, restarts), fitted
        rate_hz, chip, state, reader_state, age_s of the last delivery, batches, last_error}}."""
        _, _, per = self._evaluate()
        sensors = {n: {k: _json_float(v) for k, v in st.items()} for n, st in per.items()}
        return {
            "source": self.backend,
            "state": self._state,
            "detail": self._detail,
            "healthy": self.healthy,
            "lost_after_s": self.lost_after_s,
            "calibration": dict(self._calibration),
            "sensors": sensors,
            "reader_fifo": self.reader.realtime if self.reader is not None else "not running",
            **(
                {
                    "reader_wake_late_max_ms": round(1e3 * self.reader.wake_late_max_s, 2),
                    "reader_wake_late": self.reader.wake_late,
                    "reader_joint_polls": self.reader.joint_polls,  # both sensors in two transfers
                    # the reader's own wait between its two transfers of a poll (its GIL waits)
                    "reader_joint_gap_max_ms": round(1e3 * self.reader.joint_gap_max_s, 2),
                }
                if self.reader is not None
                else {}
            ),
            **({"bus": stats()} if (stats := getattr(self.bus, "stats", None)) is not None else {}),
        }

    # --- calibration ---------------------------------------------------------------------------------
    async def calibrate(self, seconds: float = 2.0) -> dict[str, object]:
        """Bias at rest from the running sensors; written to the calibration file and applied
        live. Returns {"file", "seconds", "sensors": {name: {"gyro_bias_deg_s", "gyro_std_deg_s",
        "accel_rest_m_s2", "samples", "chip"}}}."""
        rate = self.settings.sample_rate_hz
        least = cal.MIN_SAMPLES / (0.9 * rate)  # the sensor clock may run 10 % slow
        longest = self.settings.calibrate_max_s
        if not (isinstance(seconds, (int, float)) and least <= seconds <= longest):
            raise UsageError(
                f"seconds = {seconds!r}: give {math.ceil(least * 10) / 10:g} .. {longest:g} s "
                f"(at least {cal.MIN_SAMPLES} samples at {rate:g} Hz)"
            )
        if self.reader is None:
            why = "devices.imu is off in the config" if self.backend == "off" else "the IMU is not running"
            raise DeviceError(f"cannot calibrate the IMUs: {why}")
        if self._collect is not None:
            raise cal.CalibrationRefused("an IMU calibration is already running: wait for its result")
        self._collect = {n: [] for n in NAMES}
        try:
            await asyncio.sleep(seconds)
            frames = self._collect
        finally:
            self._collect = None
        raw: dict[str, np.ndarray] = {}
        for name in NAMES:
            got = np.concatenate(frames[name]) if frames[name] else np.zeros((0, 6), dtype=np.int16)
            if len(got) < 0.5 * seconds * rate:
                state, detail, _ = self._evaluate()
                raise DeviceError(
                    f"{name} IMU delivered {len(got)} samples in {seconds:g} s, expected about "
                    f"{seconds * rate:.0f} (IMU {state}{': ' + detail if detail else ''}): "
                    "check the sensor, then calibrate again"
                )
            raw[name] = got
        chips = {n: s.chip for n, s in self._sensors.items()}
        result = await asyncio.to_thread(self._fit_and_save, raw, chips)
        for name, c in result.items():  # live: the reader reads gyro_bias per batch
            self._sensors[name].gyro_bias = np.asarray(c.gyro_bias_rad_s, dtype=float)
        path = self.settings.calibration_file
        self._calibration = {"file": str(path), "applied": True}
        log.info("IMU calibrated (%g s), written to %s and applied", seconds, path)
        return {
            "file": str(path),
            "seconds": seconds,
            "sensors": {
                n: {
                    "gyro_bias_deg_s": np.degrees(c.gyro_bias_rad_s).round(4).tolist(),
                    "gyro_std_deg_s": np.degrees(c.gyro_std_rad_s).round(4).tolist(),
                    "accel_rest_m_s2": np.round(c.accel_rest_m_s2, 4).tolist(),
                    "samples": c.samples,
                    "chip": c.chip,
                }
                for n, c in result.items()
            },
        }

    def _fit_and_save(
        self, raw: dict[str, np.ndarray], chips: dict[str, str]
    ) -> dict[str, cal.SensorCalibration]:
        """Off the loop's thread: SI units, the motion check and bias, the file."""
        result = {}
        for name, frames in raw.items():
            accel, gyro = to_si(frames, self.settings)  # raw: no bias removed
            result[name] = cal.calibrate_sensor(name, accel, gyro, chips.get(name, ""))
        path = self.settings.calibration_file
        try:
            cal.save(path, result)
        except OSError as exc:
            raise DeviceError(
                f"cannot write the IMU calibration to {path} ({exc.strerror or exc}): give the "
                "daemon write access to that directory (systemd: StateDirectory=tvsd) or set "
                "imu.calibration_file; nothing was applied"
            ) from exc
        return result

    # --- SIL fault injection ---------------------------------------------------------------------------
    def inject(self, kind: str, sensor: str | None = None) -> dict[str, object]:
        """SIL: "loss" makes the twin bus stop answering (both sensors, or `sensor`), "restore"
        ends every injected fault. UsageError on hardware, for an unknown kind or sensor."""
        if self.backend != "sil":
            raise UsageError(
                f"IMU fault injection is for the simulated sensors (devices.imu: sil); this IMU is "
                f"{self.backend}: unplug a sensor to test a loss"
            )
        if kind not in INJECT_KINDS or (sensor is not None and sensor not in NAMES):
            raise UsageError(f"inject {kind!r} {sensor!r}: kind one of {INJECT_KINDS}, sensor pl, sa or none")
        if self.bus is None:
            raise DeviceError("cannot inject an IMU fault: the IMU is not running")
        from tvsd.sim.i2c_bus import Fault, SimI2CBus

        tell = getattr(self.plant, "imu_fault", None)
        if tell is not None:  # the twins in the SIL devices' process: told, not waited for
            tell(kind, None if sensor is None or kind != "loss" else self.settings.addresses[sensor])
            self._injected = [*self._injected, kind] if kind == "loss" else []
            return {"injected": kind, "sensor": sensor or "all", "faults": len(self._injected)}
        bus = self.bus
        assert isinstance(bus, SimI2CBus)
        if kind == "loss":
            addr = None if sensor is None else self.settings.addresses[sensor]
            fault = Fault("disconnect", bus.clock.now(), math.inf, addr)  # on the twins' clock
            self._injected.append(fault)
            bus.faults = [*bus.faults, fault]  # a new list: the reader thread iterates the old one
        else:
            bus.faults = [f for f in bus.faults if f not in self._injected]
            self._injected.clear()
        return {"injected": kind, "sensor": sensor or "all", "faults": len(self._injected)}
