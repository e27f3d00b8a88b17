"""The simulated IMU bench behind ``tvsctl imu --sil``: the bus, the two twins and their motion.

It owns the SIL wiring and its options: the twins (tvsd.sim.mpu6050) on a simulated clock (or the
wall clock with --realtime); the SA sensor's motion from the SIL drive model spinning at --rps
(--motion plant, the default; --effect switches the model's effects on) or from SyntheticMotion
(--motion synthetic); the PL sensor's from SyntheticMotion; faults injected with --sil-fault and a
wrong chip id with --sil-who-am-i. The commands that capture from it are `tvsd.cli.imu`.
"""

from __future__ import annotations

import argparse

import numpy as np

from tvsd.cli import argtypes
from tvsd.control.setup import Setup
from tvsd.errors import UsageError
from tvsd.hw.imu_clock import Clock, ManualClock, MonotonicClock
from tvsd.hw.imu_settings import SA_AXES, ImuSettings
from tvsd.sim.i2c_bus import FAULT_KINDS, Fault, SimI2CBus
from tvsd.sim.imu_motion import ArrayMotion, MotionSource, SyntheticParams, synthetic_pair
from tvsd.sim.mpu6050 import SimMpu6050, sil_pair


def add_sil_arguments(p: argparse.ArgumentParser) -> None:
    """The options that shape the simulated bench (all but --sil itself)."""
    p.add_argument("--realtime", action="store_true", help="with --sil: run at wall-clock pace")
    p.add_argument(
        "--rps",
        type=argtypes.number(0, 100, "rev/s"),
        default=25.0,
        help="--sil: rotation rate, rev/s",
    )
    p.add_argument(
        "--imbalance",
        type=argtypes.number(0, 1e4, "rad/s^2"),
        default=2.0,
        help="--sil: line at rps, rad/s^2",
    )
    p.add_argument(
        "--vibration",
        type=argtypes.number(0, 1e4, "rad/s^2"),
        default=0.3,
        help="--sil: OU std, rad/s^2",
    )
    p.add_argument("--resonance-hz", type=argtypes.number(0, 1e4, "Hz"), default=0.0)
    p.add_argument(
        "--resonance",
        type=argtypes.number(0, 1e4, "rad/s^2"),
        default=0.0,
        help="--sil: its amplitude, rad/s^2",
    )
    p.add_argument("--gamma-deg", type=argtypes.number(-90, 90, "deg"), default=0.0, help="--sil: rod tilt")
    p.add_argument(
        "--motion",
        choices=("plant", "synthetic"),
        default="plant",
        help="--sil: SA motion from the SIL drive model (default) or a synthetic source",
    )
    p.add_argument(
        "--effect",
        action="append",
        default=None,
        metavar="NAME:k=v,...",
        help="--sil with the plant: effects of the drive model (tvsctl sim spin --help)",
    )
    p.add_argument("--seed", type=argtypes.seed, default=0)
    p.add_argument("--sil-fault", action="append", default=[], metavar="KIND:START:END[:SENSOR]")
    p.add_argument("--sil-who-am-i", type=lambda s: int(s, 0), default=None)


def parse_fault(spec: str, settings: ImuSettings) -> Fault:
    """One --sil-fault KIND:START:END[:pl|sa], or UsageError saying the expected form."""
    parts = spec.split(":")
    try:
        kind, start, end = parts[0], float(parts[1]), float(parts[2])
        addr = settings.addresses[parts[3]] if len(parts) > 3 else None
        return Fault(kind, start, end, addr)
    except (IndexError, ValueError, KeyError) as exc:
        raise UsageError(
            f"--sil-fault {spec!r}: expected KIND:START:END[:pl|sa], KIND one of "
            f"{', '.join(FAULT_KINDS)}, times in s"
        ) from exc


def sil_bench(
    args: argparse.Namespace, settings: ImuSettings, at_rest: bool
) -> tuple[SimI2CBus, Clock, dict[str, SimMpu6050]]:
    """The simulated bus with both twins on it, their clock, and the twins by sensor name."""
    clock: Clock = MonotonicClock() if args.realtime else ManualClock()
    params = SyntheticParams(
        rps=0.0 if at_rest else args.rps,
        imbalance_rad_s2=0.0 if at_rest else args.imbalance,
        vibration_std_rad_s2=0.0 if at_rest else args.vibration,
        resonance_hz=args.resonance_hz,
        resonance_rad_s2=0.0 if at_rest else args.resonance,
        gamma_rad=np.radians(args.gamma_deg),
        axis=SA_AXES[settings.sa_axis],
        seed=args.seed,
    )
    motions: dict[str, MotionSource] = dict(synthetic_pair(params))
    if args.motion == "plant" and not at_rest:
        motions["sa"] = plant_motion(args, SA_AXES[settings.sa_axis])
    bus, devices = sil_pair(settings, clock, motions, bus_hz=None if args.realtime else 400e3, seed=args.seed)
    bus.faults = [parse_fault(s, settings) for s in args.sil_fault]
    if args.sil_who_am_i is not None:
        for dev in devices.values():
            dev.who_am_i = dev.regs[0x75] = args.sil_who_am_i
    return bus, clock, devices


def plant_motion(args: argparse.Namespace, axis: int) -> MotionSource:
    """The SA sensor's motion from the SIL drive model spinning at --rps (config/tvsd.yaml): the
    disturbance acceleration about the SA axis the plant computes, with --imbalance (rad/s²) as an
    imbalance torque J·α unless --effect names the effects. The vibration is the OU reading of
    eq. (12) with std --vibration (MODEL-NOTES §4): what an IMU measures is band-limited; the
    literal SDE's acceleration is white to 5 kHz and would alias into the 1 kHz samples."""
    from tvsd.causes import parse_effects
    from tvsd.config import VibrationConfig, load_config
    from tvsd.sim import runs

    cfg = load_config()
    texts = list(args.effect or [])
    if not texts and args.imbalance > 0:
        texts.append(f"imbalance:amplitude={args.imbalance * cfg.plant.J:.6g},phase=0")
    vib = VibrationConfig(model="ou", sigma_v=args.vibration, tau_n_s=cfg.sil_or_default.vibration.tau_n_s)
    setup = Setup.from_config(cfg, effects=parse_effects(texts), vibration=vib, seed=args.seed)
    settle = abs(args.rps) / cfg.control.scan_accel_rps2 + 1.0  # spin up, then capture
    trace = runs.spin(setup, args.rps, settle + args.seconds + 1.0, decim=1)
    keep = trace.t >= settle - 0.5
    t = trace.t[keep] - settle
    return ArrayMotion(t, trace.disturbance[keep], np.radians(args.gamma_deg), trace.omega[keep], axis=axis)
