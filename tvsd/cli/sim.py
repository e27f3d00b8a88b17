"""`tvsctl sim …`: offline runs of the drive model (no daemon needed)."""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

from tvsd.causes import Effect, catalogue_help, parse_effects
from tvsd.cli import argtypes
from tvsd.cli.output import print_json, print_pairs, print_table, warn
from tvsd.config import Config, Gains, load_config
from tvsd.errors import EXIT_OK, UsageError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    sim = sub.add_parser(
        "sim",
        help="offline simulation of the scanning-aperture drive",
        description="Offline runs of the drive model and the robust controller.",
    )
    simsub = sim.add_subparsers(dest="sim_command", metavar="RUN", parser_class=type(sim))
    simsub.required = True

    def common(p: argparse.ArgumentParser, params_default: str = "default") -> None:
        p.add_argument("--config", type=Path, help="scanner config file (default: config/tvsd.yaml)")
        p.add_argument(
            "--params",
            choices=("default", "paper"),
            default=params_default,
            help=f"parameter set when --config is not given (default: {params_default})",
        )
        p.add_argument("--json", action="store_true", help="print one JSON object")
        p.add_argument("--plot", type=Path, metavar="FILE.png", help="draw the figure into FILE.png")

    step = simsub.add_parser("step", help="position step response (paper Table 6, Figs. 14–16)")
    common(step)
    step.add_argument("--ref-deg", type=float, required=True, help="reference position, degrees")
    step.add_argument("--gains", type=_gains, metavar="Gp,Gd,Gr,G0", help="override the config's gains")
    step.add_argument("--seconds", type=float, default=1.0, help="simulated time (default 1 s)")
    step.set_defaults(func=_step)

    t6 = simsub.add_parser("table6", help="reproduce the paper's Table 6 (settling times)")
    common(t6, params_default="paper")
    t6.add_argument(
        "--ku",
        type=argtypes.number(0, 1e4, "V/V", low_open=True),
        help="drive gain ku (default: the config's table6_ku)",
    )
    t6.set_defaults(func=_table6)

    eff_help = "switch an effect on (repeatable), NAME:key=value,...; effects:\n" + catalogue_help()
    spin = simsub.add_parser(
        "spin",
        help="spin up to a speed; speed steadiness and vibration line",
        formatter_class=argparse.RawTextHelpFormatter,
    )
    common(spin)
    spin.add_argument("--rps", type=float, required=True, help="speed setpoint, rev/s")
    spin.add_argument("--seconds", type=float, default=10.0, help="simulated time (default 10 s)")
    spin.add_argument("--effect", action="append", default=None, metavar="NAME:k=v,...", help=eff_help)
    spin.add_argument("--seed", type=argtypes.seed, help="random seed (default: the SIL profile's)")
    spin.set_defaults(func=_spin)

    rec = simsub.add_parser(
        "record",
        help="write a SIL recording (recording CSV contract)",
        formatter_class=argparse.RawTextHelpFormatter,
    )
    rec.add_argument("--config", type=Path, help="scanner config file (default: config/tvsd.yaml)")
    rec.add_argument("--params", choices=("default", "paper"), default="default")
    rec.add_argument("--out", type=Path, required=True, metavar="FILE.csv")
    rec.add_argument(
        "--profile",
        choices=("steps", "multisine", "spin", "identify"),
        default="steps",
        help="steps: open-loop voltage staircase; multisine: open-loop PRBS on a multisine;\n"
        "spin: scanning mode to --rps (closed loop; writes omega_ref, phi_ref);\n"
        "identify: spin, then tvsctl identify's excitation (config identify:) on top",
    )
    rec.add_argument(
        "--u-unit",
        choices=("V", "A", "N*m", "duty"),
        default="V",
        help="what the u column is: drive voltage, motor current, torque kM*i, or duty (u_scale = limit)",
    )
    rec.add_argument(
        "--rps",
        type=argtypes.number(-100, 100, "rev/s"),
        default=20.0,
        help="spin profile speed (default 20 rev/s)",
    )
    rec.add_argument("--seconds", type=float, default=60.0, help="length (default 60 s)")
    rec.add_argument("--effect", action="append", default=None, metavar="NAME:k=v,...", help=eff_help)
    rec.add_argument("--seed", type=argtypes.seed, default=1)
    rec.add_argument(
        "--sigma-v",
        type=float,
        metavar="S",
        help="vibration level σv of the SIL profile's model (paper: 0.0838, 0.3381, 0.8069)",
    )
    rec.add_argument("--json", action="store_true", help="print one JSON object")
    rec.add_argument("--plot", type=Path, metavar="FILE.png", help="draw the recorded signals into FILE.png")
    rec.set_defaults(func=_record)

    from tvsd.cli import sim_scan

    sim_scan.register(simsub)


def _gains(text: str) -> Gains:
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not four numbers Gp,Gd,Gr,G0") from None
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(
            f"'{text}' must be four numbers Gp,Gd,Gr,G0, e.g. 6.31,0.5,18.89,100"
        )
    try:
        return Gains(Gp=values[0], Gd=values[1], Gr=values[2], G0=values[3])
    except UsageError as exc:
        raise argparse.ArgumentTypeError(f"'{text}': {exc}") from None


def _config(args: argparse.Namespace) -> Config:
    return load_config(args.config) if args.config else load_config(params=args.params)


def _effects(args: argparse.Namespace) -> tuple[Effect, ...] | None:
    return None if args.effect is None else parse_effects(args.effect)


def _seconds(value: float, lo: float, hi: float) -> float:
    if not lo <= value <= hi:
        raise UsageError(f"--seconds {value:g} is outside [{lo:g}, {hi:g}] s")
    return value


def _step(args: argparse.Namespace) -> int:
    from tvsd.sim import experiments

    cfg = _config(args)
    res = experiments.step(cfg, args.ref_deg, args.seconds, gains=args.gains)
    if args.plot:
        from tvsd.sim.plots import step_plot

        g = args.gains or cfg.control.gains
        step_plot(
            res.trace,
            math.radians(args.ref_deg),
            res.settling_time_s,
            f"{cfg.plant.name}: step to {args.ref_deg:g}° "
            f"(Gp,Gd,Gr,G0 = {g.Gp:g},{g.Gd:g},{g.Gr:g},{g.G0:g})",
            args.plot,
        )
    if args.json:
        print_json(res.as_dict())
    else:
        for w in res.warnings:
            warn(w)
        print_pairs(
            {
                "reference (deg)": res.ref_deg,
                "settling time 2 % (s)": res.settling_time_s,
                "overshoot (%)": res.overshoot_pct,
                "final (deg)": res.final_deg,
            }
        )
    return EXIT_OK


def _table6(args: argparse.Namespace) -> int:
    from tvsd.sim import experiments

    res = experiments.table6(_config(args), ku=args.ku)
    if args.plot:
        from tvsd.sim.plots import table6_plot

        table6_plot(
            [r.ref_deg for r in res.rows],
            [r.paper_s for r in res.rows],
            [r.ours_s for r in res.rows],
            f"Table 6: settling times (ku = {res.ku:g}; rms error {res.rms_error_pct:.2f} %)",
            args.plot,
        )
    if args.json:
        print_json(res.as_dict())
        return EXIT_OK
    print(f"Table 6 reproduction (ku = {res.ku:g}, gains {res.gains.as_tuple()}, 2 % band)")
    print_table(
        [(r.ref_deg, r.paper_s, r.ours_s, f"{r.error_pct:+.1f}") for r in res.rows],
        ["ref (deg)", "paper (s)", "ours (s)", "error (%)"],
    )
    print(f"rms error: {res.rms_error_pct:.2f} %")
    return EXIT_OK


def _spin(args: argparse.Namespace) -> int:
    from tvsd.sim import experiments

    cfg = _config(args)
    res = experiments.spin(cfg, args.rps, args.seconds, effects=_effects(args), seed=args.seed)
    if args.plot:
        from tvsd.sim.plots import spin_plot

        spin_plot(
            res.trace,
            args.rps,
            res.steady_from_s,
            res.spectrum,
            res.dominant_hz,
            f"{cfg.plant.name}: spin at {args.rps:g} rev/s, effects: {', '.join(res.effects) or 'none'}",
            args.plot,
        )
    if args.json:
        print_json(res.as_dict())
        return EXIT_OK
    print_pairs(
        {
            "speed setpoint (rev/s)": args.rps,
            "speed mean (rev/s)": res.rps_mean,
            "speed std (rev/s)": res.rps_std,
            "ω std (rad/s)": res.omega_std_rad_s,
            "dominant vibration line (Hz)": (
                res.dominant_hz if res.dominant_hz is not None else "none above the noise floor"
            ),
            "its amplitude (rad/s²)": (
                res.dominant_amplitude_rad_s2 if res.dominant_amplitude_rad_s2 is not None else "—"
            ),
            "PSD / noise floor there": f"{res.line_to_floor:.2f} (a line needs > {res.line_threshold:.2f})",
            "steady from (s)": res.steady_from_s,
            "vibration model": res.vibration_model,
            "effects": ", ".join(res.effects) or "none",
        }
    )
    if args.plot:
        print(f"plot: {args.plot}")
    return EXIT_OK


def _record(args: argparse.Namespace) -> int:
    from tvsd.sim.record import record

    cfg = _config(args)
    seconds = _seconds(args.seconds, 1.0, 3600.0)
    effects = _effects(args) or ()
    if args.profile in ("spin", "identify") and not 0.5 <= abs(args.rps) <= 100:
        raise UsageError(f"--rps {args.rps:g} is outside the drive's range 0.5–100 rev/s (either sign)")
    if args.sigma_v is not None:
        if not 0 <= args.sigma_v <= 100 or not math.isfinite(args.sigma_v):
            raise UsageError(f"--sigma-v {args.sigma_v:g} is outside [0, 100]")
        sil = cfg.sil_or_default
        vib = dataclasses.replace(sil.vibration, sigma_v=args.sigma_v)
        cfg = dataclasses.replace(cfg, sil=dataclasses.replace(sil, vibration=vib))
    if args.plot is not None and args.plot.suffix.lower() != ".png":  # before the run, not after
        raise UsageError(f"--plot {args.plot}: the plot is written as PNG; give a file name ending in .png")
    res = record(cfg, args.out, args.profile, seconds, effects, args.seed, args.rps, args.params, args.u_unit)
    if args.plot:
        from tvsd.sim.plots import record_plot

        record_plot(res.path, args.plot)
    if args.json:
        print_json(
            {
                "path": str(res.path),
                "profile": res.profile,
                "seconds": res.seconds,
                "rows": res.rows,
                "sample_rate_hz": res.sample_rate_hz,
            }
        )
    else:
        print(
            f"wrote {res.rows} rows ({res.seconds:g} s at {res.sample_rate_hz:g} Hz, profile "
            f"{res.profile}) to {res.path}"
        )
    return EXIT_OK
