"""tvsctl imu — capture and calibrate the two MPU6050s, on the bus or on their simulated twins.

  tvsctl imu capture [--sil] [--seconds S] [--out FILE] [--json] [--plot FILE.png]
  tvsctl imu calibrate [--sil [--data-dir DIR]] [--seconds S] [--out FILE] [--json]
  tvsctl imu bench [--seconds S] [--json]

This module owns the commands: capture, the SA line's analysis, the samples file, calibration and
the bench. --sil runs them on the simulated twins, faster than real time unless --realtime; that
bench and its options (--rps, --motion, --effect, --sil-fault...) are `tvsd.cli.imu_sil`.

Samples file (--out), one file for both sensors, read back by read_samples():
  # tvs-imu: 1
  # sample_rate_hz: 1000          nominal; the fitted rates follow
  # rate_hz_pl: 1026.99           (also rate_hz_sa, lost_pl, lost_sa, sa_axis, gyro_bias_removed)
  t,sensor,ax,ay,az,gx,gy,gz      t s on the fitted sensor clock (a jump = lost samples),
                                  sensor pl|sa, accel m/s^2, gyro rad/s
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvsd.cli import argtypes
from tvsd.cli.imu_sil import add_sil_arguments, sil_bench
from tvsd.cli.output import print_json
from tvsd.daemon.main import DEFAULT_DATA
from tvsd.errors import EXIT_OK, DataFileError, DeviceError, UsageError
from tvsd.hw import imu_calibration as cal
from tvsd.hw.angular_acceleration import angular_acceleration
from tvsd.hw.i2c_bus import open_bus
from tvsd.hw.imu_clock import Clock, ManualClock, MonotonicClock
from tvsd.hw.imu_reader import ImuReader
from tvsd.hw.imu_sensor_reader import SensorReader
from tvsd.hw.imu_settings import SA_AXES, ImuSettings
from tvsd.hw.mpu6050 import Mpu6050, SMBusLike
from tvsd.hw.mpu6050 import bus_budget as _bus_budget
from tvsd.hw.mpu6050_registers import DLPF_DELAY_S
from tvsd.sim.mpu6050 import sil_pair

NAMES = ("pl", "sa")
LINE_MIN_HZ = 2.0  # below: the mounts' leak and drift, not vibration lines


@dataclass
class SensorRecord:
    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    rate_hz: float
    status: dict[str, object]


def run_capture(
    bus: SMBusLike,
    settings: ImuSettings,
    clock: Clock,
    seconds: float,
    gyro_bias: dict[str, np.ndarray] | None = None,
) -> dict[str, SensorRecord]:
    """Capture from both sensors; times from each sensor's final clock fit."""
    readers = [
        SensorReader(Mpu6050(bus, n, settings, clock.sleep), clock, (gyro_bias or {}).get(n)) for n in NAMES
    ]
    batches = ImuReader(readers, clock).run_for(seconds)
    out = {}
    for r in readers:
        mine = [b for b in batches if b.sensor == r.name]
        if not mine:
            raise DeviceError(f"{r.name} IMU delivered no samples: {r.last_error or 'no data'}")
        t = np.concatenate([r.fit.times(b.k, b.epoch) for b in mine])
        out[r.name] = SensorRecord(
            t,
            np.concatenate([b.accel for b in mine]),
            np.concatenate([b.gyro for b in mine]),
            r.fit.rate(),
            r.status(),
        )
    return out


def sa_alpha(rec: SensorRecord, axis: int) -> tuple[np.ndarray, float]:
    """Angular acceleration about the SA axis over the longest gap-free run, and its rate.

    Filling gaps would put flat stretches into the record, and a flat-top window weighs the
    middle of the record most: a gap there costs far more line amplitude than its length.
    """
    fs = rec.rate_hz
    k = np.rint((rec.t - rec.t[0]) * fs).astype(np.int64)
    breaks = np.flatnonzero(np.diff(k) != 1) + 1
    runs = np.split(np.arange(len(k)), breaks)
    best = max(runs, key=len)
    return angular_acceleration(rec.gyro[best, axis], fs), fs


def dominant_line(alpha: np.ndarray, fs: float) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Frequency and amplitude (rad/s^2) of the strongest line above LINE_MIN_HZ.

    Flat-top window: a line's amplitude is read to ~0.1 % wherever it falls between bins.
    """
    from scipy.signal import periodogram

    f, p = periodogram(alpha - alpha.mean(), fs, window="flattop", scaling="spectrum")
    band = (f >= LINE_MIN_HZ) & (f <= 0.4 * fs)
    i = int(np.argmax(np.where(band, p, -1.0)))
    lobe = slice(max(i - 3, 0), i + 4)  # the flat-top main lobe: its centroid beats one bin
    centre = float(np.sum(f[lobe] * p[lobe]) / np.sum(p[lobe]))
    return centre, float(np.sqrt(2 * p[i])), f, p


def write_samples(path: Path, recs: dict[str, SensorRecord], settings: ImuSettings, calibrated: bool) -> None:
    lines = ["# tvs-imu: 1", f"# sample_rate_hz: {settings.sample_rate_hz:g}"]
    lines += [f"# rate_hz_{n}: {r.rate_hz:.4f}" for n, r in recs.items()]
    lines += [f"# lost_{n}: {r.status['lost']}" for n, r in recs.items()]
    lines += [f"# sa_axis: {settings.sa_axis}", f"# gyro_bias_removed: {str(calibrated).lower()}"]
    lines.append("t,sensor,ax,ay,az,gx,gy,gz")
    try:
        with open(path, "w") as f:
            f.write("\n".join(lines) + "\n")
            for n, r in recs.items():
                data = np.column_stack([r.t, r.accel, r.gyro])
                for row in data:
                    f.write(f"{row[0]:.6f},{n}," + ",".join(f"{v:.6g}" for v in row[1:]) + "\n")
    except OSError as exc:
        raise DataFileError(f"{path}: cannot write samples ({exc.strerror})") from exc


def read_samples(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """Read a samples file: {sensor: {"t", "accel", "gyro"}} plus metadata under "meta"."""
    meta: dict[str, str] = {}
    try:
        with open(path) as f:
            head = f.readline().strip()
            if head != "# tvs-imu: 1":
                raise DataFileError(f"{path}: line 1 is {head!r}, expected '# tvs-imu: 1'")
            header = ""
            for line in f:
                if not line.startswith("#"):
                    header = line.strip()
                    break
                key, _, value = line[1:].partition(":")
                meta[key.strip()] = value.strip()
            if header != "t,sensor,ax,ay,az,gx,gy,gz":
                raise DataFileError(f"{path}: header {header!r}, expected t,sensor,ax,ay,az,gx,gy,gz")
            rows = [line.rstrip("\n").split(",") for line in f if line.strip()]
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read ({exc.strerror})") from exc
    out: dict[str, dict[str, np.ndarray]] = {}
    for name in sorted({r[1] for r in rows}):
        mine = [r for r in rows if r[1] == name]
        try:
            data = np.array([[float(v) for v in (r[0], *r[2:])] for r in mine])
        except (ValueError, IndexError) as exc:
            raise DataFileError(f"{path}: sensor {name}: bad number or column count ({exc})") from exc
        if data.shape[1] != 7 or not np.all(np.isfinite(data)) or np.any(np.diff(data[:, 0]) <= 0):
            raise DataFileError(f"{path}: sensor {name}: 7 finite columns, t increasing expected")
        out[name] = {"t": data[:, 0], "accel": data[:, 1:4], "gyro": data[:, 4:7]}
    out["meta"] = {k: np.array(v) for k, v in meta.items()}
    return out


def _settings(args: argparse.Namespace) -> ImuSettings:
    """The config's imu: section (config/tvsd.yaml or --config), with --bus overriding the bus."""
    from dataclasses import replace

    from tvsd.config import load_config

    settings: ImuSettings = (load_config(args.config) if args.config else load_config()).imu
    return replace(settings, bus=args.bus) if args.bus is not None else settings


def _setup(args: argparse.Namespace, at_rest: bool) -> tuple[ImuSettings, SMBusLike, Clock]:
    if not 0.5 <= args.seconds <= 3600:
        raise UsageError(f"--seconds {args.seconds:g}: use 0.5 .. 3600")
    settings = _settings(args)
    if args.sil:
        bus, clock, _ = sil_bench(args, settings, at_rest)
        return settings, bus, clock
    return settings, open_bus(settings), MonotonicClock()


def cmd_capture(args: argparse.Namespace) -> int:
    settings, bus, clock = _setup(args, at_rest=False)
    if args.calibration:  # asked for: it must be there
        calib: dict[str, cal.SensorCalibration] | None = cal.load(args.calibration)
    elif args.sil:  # the twins have their own biases; a real file would not fit them
        calib = None
    else:
        calib = cal.load_or_none(settings.calibration_file)
    bias = {n: np.asarray(c.gyro_bias_rad_s) for n, c in (calib or {}).items()}
    try:
        recs = run_capture(bus, settings, clock, args.seconds, bias)
    finally:
        bus.close()
    alpha, fs = sa_alpha(recs["sa"], SA_AXES[settings.sa_axis])
    f_peak, amp, f, p = dominant_line(alpha, fs)
    result: dict[str, object] = {
        "sensors": {
            n: {
                "rate_hz": round(r.rate_hz, 3),
                **{
                    k: r.status[k]
                    for k in (
                        "samples",
                        "overflows",
                        "errors",
                        "lost",
                        "resyncs",
                        "restarts",
                        "state",
                        "chip",
                    )
                },
            }
            for n, r in recs.items()
        },
        "dominant_hz": round(f_peak, 3),
        "peak_rad_s2": round(amp, 4),
        "spectrum_s": round(len(alpha) / fs, 3),
        "dlpf_delay_s": DLPF_DELAY_S[settings.dlpf_cfg],  # not removed from the times
        "calibrated": calib is not None,
        "source": "sil" if args.sil else f"i2c-{settings.bus}",
    }
    if args.sil:
        result["rotation_hz"] = args.rps
    if args.out:
        write_samples(args.out, recs, settings, calib is not None)
        result["out"] = str(args.out)
    if args.plot:
        _plot(args.plot, f, p, f_peak, recs)
        result["plot"] = str(args.plot)
    if args.json:
        print_json(result)
    else:
        for n, s in result["sensors"].items():  # type: ignore[attr-defined]
            print(
                f"{n}: {s['chip']}, {s['rate_hz']} Hz, {s['samples']} samples, {s['lost']} lost, "
                f"{s['overflows']} overflows, {s['errors']} errors, {s['state']}"
            )
        print(
            f"SA angular acceleration: dominant line {f_peak:.2f} Hz, {amp:.3g} rad/s^2 "
            f"(longest gap-free {len(alpha) / fs:.2f} s)"
        )
        if calib is None:
            print("uncalibrated (no gyro bias removed): run `tvsctl imu calibrate` at rest")
    return EXIT_OK


def _plot(path: Path, f: np.ndarray, p: np.ndarray, f_peak: float, recs: dict[str, SensorRecord]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    ax.semilogy(f, np.sqrt(2 * p) + 1e-9, lw=0.8, label="SA angular acceleration")
    ax.axvline(f_peak, color="r", ls=":", label=f"{f_peak:.2f} Hz")
    ax.set(xlabel="frequency (Hz)", ylabel="amplitude (rad/s²)", xlim=(0, 0.4 * recs["sa"].rate_hz))
    ax.set_title("SA angular acceleration about the SA axis (Δv), longest gap-free run")
    ax.legend()
    fig.tight_layout()
    try:
        fig.savefig(path)
    except OSError as exc:
        raise DataFileError(f"{path}: cannot write plot ({exc.strerror})") from exc
    finally:
        plt.close(fig)


def cmd_calibrate(args: argparse.Namespace) -> int:
    settings, bus, clock = _setup(args, at_rest=not args.sil_moving)
    try:
        recs = run_capture(bus, settings, clock, args.seconds)
    finally:
        bus.close()
    result = {n: cal.calibrate_sensor(n, r.accel, r.gyro, str(r.status["chip"])) for n, r in recs.items()}
    # --sil: the SIL daemon's file in its data directory, never the board's (its biases differ)
    out = args.out or (args.data_dir / cal.SIL_FILE_NAME if args.sil else settings.calibration_file)
    try:
        cal.save(out, result)
    except OSError as exc:
        raise DataFileError(f"{out}: cannot write calibration ({exc}); pass --out FILE") from exc
    sensors = {
        n: {"gyro_bias_deg_s": np.degrees(c.gyro_bias_rad_s).round(4).tolist(), "samples": c.samples}
        for n, c in result.items()
    }
    if args.json:
        print_json({"file": str(out), "sensors": sensors})
    else:
        for n, v in sensors.items():
            print(f"{n}: gyro bias {v['gyro_bias_deg_s']} deg/s ({v['samples']} samples)")
        print(f"written to {out}")
    return EXIT_OK


def bench_capture(seconds: float = 5.0) -> dict[str, float]:
    """Host CPU per second of capture (two twins at 1 kHz, simulated clock) and the bus budget.

    The twins' own sample generation is timed apart and subtracted: what remains is driver +
    reader + the bus object's call overhead (a real bus adds the kernel's ioctl time).
    """
    settings = ImuSettings()
    clock = ManualClock()
    bus, devices = sil_pair(settings, clock, signal="counter", bus_hz=400e3)
    readers = [SensorReader(Mpu6050(bus, n, settings, clock.sleep), clock) for n in NAMES]
    reader = ImuReader(readers, clock)
    reader.run_for(0.5)  # bring-up and first fits out of the way: measure the steady state
    bus.bits = 0
    twin0 = sum(d.cpu_s for d in devices.values())
    t0 = time.process_time()
    reader.run_for(seconds)
    total = time.process_time() - t0
    twin = sum(d.cpu_s for d in devices.values()) - twin0
    budget = _bus_budget(settings, burst=reader.joint)  # what this reader sends: joint polls burst
    return {
        "capture_s": seconds,
        "cpu_s_per_s_host": (total - twin) / seconds,
        "cpu_s_per_s_twin": twin / seconds,
        "sim_bus_bits_per_s": bus.bits / seconds,
        **budget,
    }


def cmd_bench(args: argparse.Namespace) -> int:
    result = bench_capture(args.seconds)
    if args.json:
        print_json(result)
    else:
        for k, v in result.items():
            print(f"{k:28s} {v:.6g}")
    return EXIT_OK


def _common(p: argparse.ArgumentParser, seconds: float) -> None:
    p.add_argument("--sil", action="store_true", help="simulated sensors (SIL plant motion)")
    p.add_argument("--seconds", type=float, default=seconds)
    p.add_argument("--json", action="store_true")
    p.add_argument("--bus", type=int, default=None, help="I2C bus number (default imu.bus)")
    p.add_argument(
        "--config", type=Path, help="scanner config with the imu: section (default config/tvsd.yaml)"
    )
    add_sil_arguments(p)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    imu = subparsers.add_parser("imu", help="MPU6050 capture, calibration, benchmark")
    sub = imu.add_subparsers(dest="imu_command", metavar="SUBCOMMAND", parser_class=type(imu))
    sub.required = True
    cap = sub.add_parser("capture", help="capture both IMUs, report the dominant line")
    _common(cap, 10.0)
    cap.add_argument("--out", type=Path, help="write the samples (CSV, see tvsd.cli.imu)")
    cap.add_argument("--plot", type=Path, help="spectrum of the SA angular acceleration (PNG)")
    cap.add_argument("--calibration", type=Path, help="calibration file (default imu's)")
    cap.set_defaults(func=cmd_capture)
    calp = sub.add_parser("calibrate", help="gyro bias at rest, saved apart from the config")
    _common(calp, 2.0)
    calp.add_argument(
        "--out", type=Path, help=f"calibration file (default imu's; with --sil DATA_DIR/{cal.SIL_FILE_NAME})"
    )
    calp.add_argument(
        "--data-dir",
        type=Path,
        default=DEFAULT_DATA,
        help=f"--sil: the SIL daemon's --data-dir, where its twins' calibration is (default {DEFAULT_DATA})",
    )
    calp.add_argument("--sil-moving", action="store_true", help="--sil: keep the motor spinning")
    calp.set_defaults(func=cmd_calibrate)
    bench = sub.add_parser("bench", help="CPU per second of capture, bus budget")
    bench.add_argument("--seconds", type=argtypes.number(0.1, 3600, "s"), default=5.0)
    bench.add_argument("--json", action="store_true")
    bench.set_defaults(func=cmd_bench)
