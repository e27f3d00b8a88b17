"""What the colour test sees on an outsider null, split into its parts (docs/measurements/colour14.md).

An outsider case is drawn again as variants that share its vibration (`seed` kept): as drawn, a
fine encoder (`cpr=4194304`: ω is then the true speed to 1e-6 of a count), no PWM (`pwm_bits=0`).
From the doctor's own rows (its residual after the held levels, the ramps, the floor):
- the encoder's quantisation in the residual, exactly: ω as drawn less ω fine, through the doctor's
  chain (band filter, central difference, anti-alias, decimation, the ramps), against the floor the
  doctor models for it, band by band, and its coherence with the rest of the residual;
- the PWM's part left after the held levels: the residual as drawn less that of `pwm_bits=0`.

    nice -n 19 .venv/bin/python scripts/colour14_probe.py o14033 [--seed-shift K] [--cause colored_noise:6]
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import csd, welch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import itertools

import outsider_bench as ob

from tvsd.analysis import doctor, noise, quantisation
from tvsd.analysis.dataset import load
from tvsd.config import load_config

seen: dict[str, Any] = {}
_gated = quantisation.gated
_analyse = doctor.analyse


def _gated_capture(prep: Any, keep: np.ndarray, residual: np.ndarray, rate: float, model: Any = None) -> Any:
    out = _gated(prep, keep, residual, rate, model)
    seen.update(prep=prep, keep=keep, raw=residual, rate=rate, model=model, resid=out[0], floor=out[1])
    return out


def _analyse_capture(resid: np.ndarray, rate: float, J: float, band: float, floor: Any = None) -> Any:
    r = _analyse(resid, rate, J, band, floor)
    seen.update(band=band, report=r)
    return r


def run(spec: ob.Spec, tmp: Path) -> dict[str, Any]:
    """The doctor on a drawn spec; what it handed the spectral tests."""
    quantisation.gated = _gated_capture  # this script's wrappers: the inputs, unchanged
    doctor.analyse = _analyse_capture
    cols = ob.make(spec)
    path = tmp / f"{spec.name}.csv"
    ob.write(path, spec, cols)
    cfg = load_config()
    seen.clear()
    d = doctor.diagnose(load(path, cfg), cfg.plant.v0)
    return dict(seen, cols=cols, cause=d.cause)


def variant(s: ob.Spec, **kw: Any) -> ob.Spec:
    v = copy.deepcopy(s)
    for k, val in kw.items():
        for d in (v.sensor, v.drive, v.noise, v.plant):
            if k in d:
                d[k] = val
                break
        else:
            setattr(v, k, val)
    return v


def chain(prep: Any, column: np.ndarray) -> np.ndarray:
    """A full-rate speed error as the acceleration rows see it (prep.accel's own path)."""
    from scipy.signal import filtfilt

    fs = prep.data.sample_rate_hz
    acc = np.gradient(filtfilt(prep.b, prep.a, column), 1.0 / fs)
    return prep.rows(acc)


def fd_theta(y: np.ndarray, X: np.ndarray, w: np.ndarray, rate: float, floor: Any, rep: Any) -> np.ndarray:
    """Least squares weighted per frequency by 1/(flat + b·f² + floor): GLS with the known floor."""
    n = len(y)
    f = np.fft.rfftfreq(n, 1.0 / rate)
    a = rep  # the residual's flat level
    S = a + (floor(f) if floor is not None else 0.0)
    print(
        f"    fd weights: S(1 Hz)/a {S[np.searchsorted(f, 1.0)] / a:.3g}, S(40 Hz)/a {S[np.searchsorted(f, 40.0)] / a:.3g}"
    )
    wt = 1.0 / S
    Y = np.fft.rfft(w * y)
    Xf = np.fft.rfft(w[:, None] * X, axis=0)
    G = (Xf.conj().T * wt) @ Xf
    g = (Xf.conj().T * wt) @ Y
    return np.linalg.lstsq(G.real, g.real, rcond=None)[0]


EDGES = [0.5, 2, 5, 7.5, 10, 15, 20, 25, 30, 40, 50]


def bands(f: np.ndarray, *series: np.ndarray) -> list[list[float]]:
    out = []
    for lo, hi in itertools.pairwise(EDGES):
        s = (f >= lo) & (f < hi)
        out.append([float(x[s].mean()) if s.any() else float("nan") for x in series])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("case")
    ap.add_argument("--seed-shift", type=int, default=0, help="another vibration: the make() seed + K")
    ap.add_argument("--cause", default=None)
    ap.add_argument("--set", dest="changes", action="append", default=[], help="KEY=VALUE on the base spec")
    ap.add_argument("--class", dest="cls", default=None, help="a class of tests/outsider_classes.py")
    ap.add_argument("--dump", default=None, help="write the rows to this .npz")
    a = ap.parse_args(argv)
    cause, size = (a.cause.split(":")[0], float(a.cause.split(":")[1])) if a.cause else ("none", 0.0)
    if a.cls:
        import outsider_classes as oc

        s = oc.spec_of(a.cls, int(a.case.lstrip("o")), cause, size)
    else:
        s = ob.draw(int(a.case.lstrip("o")), cause, size)
    s.seed += a.seed_shift
    for kv in a.changes:
        k, v = kv.split("=")
        s = variant(s, **{k: type(s.sensor.get(k, s.drive.get(k, 0.0)))(float(v))})
    tmp = Path(tempfile.mkdtemp(prefix="c14probe"))
    base = run(s, tmp)
    fine = run(variant(s, cpr=4194304), tmp)
    nopwm = run(variant(s, pwm_bits=0), tmp) if s.drive["pwm_bits"] else None
    prep, rate, band = base["prep"], base["rate"], base["band"]
    rep = base["report"]
    print(f"{s.name}: {s.unit} {s.excitation} {s.fs:g} Hz {s.seconds:g} s cpr {s.sensor['cpr']} "
          f"pwm {s.drive['pwm_bits']} σv {s.noise['sigma_v']:.3g}; answer {base['cause']}, colour p "
          f"{rep.colour_p:.3g} τ {rep.tau_s * 1e3:.1f} ms band {rep.colour_band_hz}; fine {fine['cause']} "
          f"p {fine['report'].colour_p:.3g}" + (f"; no PWM {nopwm['cause']} p {nopwm['report'].colour_p:.3g}" if nopwm else ""))  # fmt: skip
    # the quantisation's exact part in the residual rows
    e_w = base["cols"]["omega"] - fine["cols"]["omega"]
    w = quantisation.edge_taper(base["keep"], rate)
    q_rows = w * chain(prep, e_w)
    resid = base["resid"]
    nper = int(noise.SEGMENT_S * rate)
    f, p_res = welch(resid - resid.mean(), fs=rate, nperseg=nper)
    _, p_q = welch(q_rows - q_rows.mean(), fs=rate, nperseg=nper)
    rest = resid - q_rows
    _, p_rest = welch(rest - rest.mean(), fs=rate, nperseg=nper)
    _, c_qr = csd(q_rows - q_rows.mean(), rest - rest.mean(), fs=rate, nperseg=nper)
    fl = base["floor"](f) if base["floor"] is not None else np.zeros_like(f)
    fw, _pw, _kw, a0, cut = noise._whole_band(f, p_res, band, base["floor"])
    print(
        f"rows {rate:g} Hz, flat a0 {a0:.4g}, floor passes it at {fw[cut] if cut < len(fw) else None} Hz; "
        f"rows kept {base['keep'].mean():.3f}"
    )
    print("  band Hz    resid/a0  quant/a0  floor/a0  quant/floor  rest/a0  2Re(cross)/a0")
    for (lo, hi), (r, qq, ff, rr, cc) in zip(itertools.pairwise(EDGES),
                                              bands(f, p_res, p_q, fl, p_rest, 2 * c_qr.real), strict=True):  # fmt: skip
        print(
            f"  {lo:4g}-{hi:<4g} {r / a0:9.3f} {qq / a0:9.3f} {ff / a0:9.3f} {qq / max(ff, 1e-300):11.3f} "
            f"{rr / a0:8.3f} {cc / a0:9.3f}"
        )
    # the regressors' own quantisation (ω, sgn ω, Stribeck columns on the coarse speed) and the fit
    X_b, X_f = base["model"][0], fine["model"][0]
    if X_b.shape == X_f.shape:
        y_b = prep.rows(prep.accel)
        kb = base["keep"] > 0
        theta, *_ = np.linalg.lstsq(X_b[kb], (y_b - base["raw"])[kb], rcond=None)
        parts = {"regressors": w * ((X_b - X_f) @ theta)}
        for j in range(X_b.shape[1]):
            parts[f"  col{j}"] = w * ((X_b[:, j] - X_f[:, j]) * theta[j])
        parts["fine resid"] = w * fine["resid"] if len(fine["resid"]) == len(w) else np.zeros_like(w)
        print(
            "  part /a0 by band: "
            + " ".join(f"{lo:g}-{hi:g}" for lo, hi in itertools.pairwise(EDGES))
        )
        for name, x in parts.items():
            _, px = welch(x - x.mean(), fs=rate, nperseg=nper)
            print(f"  {name:12s} " + " ".join(f"{b[0] / a0:.3f}" for b in bands(f, px)))
    if X_b.shape == X_f.shape:  # the residual with other coefficients, the same levels and ramps
        from tvsd.analysis.command_levels import without_levels
        from tvsd.analysis.gls import gls

        kb = base["keep"] > 0
        y_b = prep.rows(prep.accel)
        y_f = fine["prep"].rows(fine["prep"].accel)
        kf = fine["keep"] > 0
        theta_f = gls(y_f, X_f, fine["model"][1], kf).theta
        theta_ols, *_ = np.linalg.lstsq(X_b[kb], y_b[kb], rcond=None)
        theta_fa = gls(y_b, X_b, fine["model"][1], kb).theta
        for name, th, ar in (("θ fine, no refit", theta_f, None), ("OLS", theta_ols, None),
                             ("GLS with fine's AR", theta_fa, fine["model"][1]),
                             ("GLS own AR (doctor)", gls(y_b, X_b, base["model"][1], kb).theta, base["model"][1]),
                             ("floor-weighted", fd_theta(y_b, X_b, w, rate, base["floor"], a0), None)):  # fmt: skip
            r = y_b - X_b @ th
            r = np.where(kb, without_levels(prep, kb, r, X_b if ar is not None else None, ar), 0.0)
            rep2 = noise.analyse(w * r, rate, 1.0, band, base["floor"])
            print(f"  colour p with {name}: {rep2.colour_p:.3g} (τ {rep2.tau_s * 1e3:.1f} ms)")
        from tvsd.analysis.design import _shift

        u = np.asarray(prep.data.u, dtype=float)
        for shifts in ((-2, 1, 2), (-4, -3, -2, 1, 2, 3, 4), (-8, -6, -4, -2, 2, 4, 6, 8)):
            Xu = np.column_stack([X_b] + [prep.band_rows(_shift(u, k)) for k in shifts])
            th = gls(y_b, Xu, base["model"][1], kb).theta
            r = np.where(kb, without_levels(prep, kb, y_b - Xu @ th, Xu, base["model"][1]), 0.0)
            rep2 = noise.analyse(w * r, rate, 1.0, band, base["floor"])
            _, pr = welch(w * r, fs=rate, nperseg=nper)
            print(
                f"  colour p with u shifted {shifts}: {rep2.colour_p:.3g} (τ {rep2.tau_s * 1e3:.1f} ms); /a0 by band "
                + " ".join(f"{b[0] / a0:.2f}" for b in bands(f, pr))
            )
    if a.dump:
        np.savez(
            a.dump,
            X_b=base["model"][0],
            X_f=fine["model"][0],
            y_b=prep.rows(prep.accel),
            y_f=fine["prep"].rows(fine["prep"].accel),
            ar=base["model"][1],
            ar_f=fine["model"][1],
            resid=resid,
            q=q_rows,
            w=w,
            keep=base["keep"],
            raw=base["raw"],
            fine=fine["resid"],
            fine_keep=fine["keep"],
            fine_raw=fine["raw"],
            u=prep.data.u,
            omega=prep.data.speed,
            omega_fine=fine["cols"]["omega"],
            trim=prep.trim,
            decim=prep.band.decim,
            a0=a0,
            nopwm=nopwm["resid"] if nopwm else np.zeros(0),
            nopwm_keep=nopwm["keep"] if nopwm else np.zeros(0),
        )
    if nopwm is not None and len(nopwm["resid"]) == len(resid):
        d = resid - nopwm["resid"]
        _, p_d = welch(d - d.mean(), fs=rate, nperseg=nper)
        print(
            "  PWM's part left (resid − resid without PWM) /a0 by band: "
            + " ".join(f"{x[0] / a0:.3f}" for x in bands(f, p_d))
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
