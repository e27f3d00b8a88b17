"""Figures for `tvsctl sim --plot FILE.png` (matplotlib, no display needed)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.errors import UsageError
from tvsd.sim.runs import Trace
from tvsd.sim.spectrum import Spectrum, shaft_orders


def figure(rows: int, cols: int, size: tuple[float, float]) -> tuple[Any, Any, Any]:
    """(pyplot, figure, axes) on the Agg backend: no display needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, cols, figsize=size)
    return plt, fig, axes


def save_png(plt: Any, fig: Any, path: Path) -> None:
    """Write a --plot figure; a wrong suffix or an unwritable path is a usage error (exit 2)."""
    if path.suffix.lower() != ".png":
        raise UsageError(f"--plot {path}: the plot is written as PNG; give a file name ending in .png")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise UsageError(f"--plot {path}: cannot write: {exc.strerror}") from exc
    finally:
        plt.close(fig)


def step_plot(trace: Trace, ref_rad: float, settling_s: float, title: str, path: Path) -> dict[str, Any]:
    """Phase portrait, position and velocity (the paper's Figs. 14–16), zoomed on the transient
    (to 3× the settling time) with the 2 % band and the settling time marked; returns what is drawn."""
    plt, fig, ax = figure(1, 3, (13, 3.8))
    end = float(trace.t[-1])
    zoom = end if not math.isfinite(settling_s) else min(end, max(3.0 * settling_s, 0.02))
    ax[0].plot(trace.phi, trace.omega, lw=1)
    ax[0].plot([ref_rad], [0], "k+", ms=12)
    ax[0].set(xlabel="φ (rad)", ylabel="ω (rad/s)", title="phase portrait (whole run)")
    ref_deg = math.degrees(ref_rad)
    ax[1].plot(trace.t, np.degrees(trace.phi), lw=1)
    ax[1].axhline(ref_deg, color="k", lw=0.8, ls="--")
    ax[1].axhspan(ref_deg - 0.02 * abs(ref_deg), ref_deg + 0.02 * abs(ref_deg), color="0.9", label="2 % band")
    ax[2].plot(trace.t, trace.omega, lw=1)
    settle = (
        "never settles in the run"
        if not math.isfinite(settling_s)
        else f"settles at {settling_s * 1e3:.1f} ms"
    )
    for a in ax[1:]:
        if math.isfinite(settling_s):
            a.axvline(
                settling_s, color="r", lw=0.9, ls=":", label=f"settling (2 %) {settling_s * 1e3:.1f} ms"
            )
        a.set_xlim(0.0, zoom)
    ax[1].set(xlabel="t (s)", ylabel="φ (deg)", title=f"position: {settle}")
    ax[2].set(xlabel="t (s)", ylabel="ω (rad/s)", title="velocity")
    ax[1].legend(fontsize=8, loc="lower right")
    shown = "whole run" if zoom >= end else f"first {zoom * 1e3:.0f} ms of {end:g} s"
    fig.suptitle(f"{title} — {shown}")
    save_png(plt, fig, path)
    return {"xlim": (0.0, zoom), "settling_s": settling_s}


def spin_plot(
    trace: Trace,
    rps: float,
    steady_from: float,
    spectrum: Spectrum,
    dominant_hz: float | None,
    title: str,
    path: Path,
) -> dict[str, Any]:
    """Speed against its reference, and the SA vibration's Welch spectrum over the whole band to
    Nyquist with its noise floor, the line threshold, the shaft orders and the reported line."""
    plt, fig, ax = figure(1, 2, (13, 4.2))
    ax[0].plot(trace.t, trace.omega_mean / (2 * math.pi), lw=0.8)
    ax[0].axhline(rps, color="k", lw=0.8, ls="--", label=f"reference {rps:g} rev/s")
    ax[0].axvline(steady_from, color="0.6", lw=0.8, ls=":", label="judged from here")
    ax[0].set(xlabel="t (s)", ylabel="speed (rev/s)", title="scanning-aperture speed")
    ax[0].legend(fontsize=8)
    sp = spectrum
    nyquist = float(sp.f[-1])
    ax[1].semilogy(
        sp.f, sp.psd, lw=0.7, label=f"Welch PSD ({sp.segments} segments, {sp.resolution_hz:.2g} Hz)"
    )
    ax[1].semilogy(sp.f, sp.floor, color="0.4", lw=0.8, label="noise floor (running median)")
    ax[1].semilogy(sp.f, sp.floor * sp.threshold, color="0.4", lw=0.8, ls="--",
                   label="line threshold (1 % false alarms)")  # fmt: skip
    orders = shaft_orders(rps, nyquist)
    for k, hz in orders:
        ax[1].axvline(
            hz, color="g", lw=0.6, ls="--", alpha=0.6, label="shaft orders 1×, 2×, …" if k == 1 else None
        )
    if dominant_hz is not None:
        ax[1].axvline(dominant_hz, color="r", lw=1.0, ls=":", label=f"reported line {dominant_hz:.2f} Hz")
        verdict = f"line at {dominant_hz:.2f} Hz"
    else:
        verdict = "no line above the noise floor"
    ax[1].set(xlabel="frequency (Hz)", ylabel="PSD ((rad/s²)²/Hz)", xlim=(0.0, nyquist),
              title=f"SA vibration spectrum: {verdict}")  # fmt: skip
    ax[1].legend(fontsize=7, loc="upper right")
    fig.suptitle(title)
    save_png(plt, fig, path)
    return {"xlim": (0.0, nyquist), "orders_hz": [hz for _, hz in orders], "dominant_hz": dominant_hz}


def table6_plot(
    refs_deg: list[float], paper_s: list[float], ours_s: list[float], title: str, path: Path
) -> None:
    """Settling time against the reference: the paper's Table 6 beside this model's."""
    plt, fig, ax = figure(1, 1, (7, 4))
    ax.plot(refs_deg, np.array(paper_s) * 1e3, "ko-", label="paper, Table 6")
    ax.plot(refs_deg, np.array(ours_s) * 1e3, "s--", color="C0", label="this model")
    ax.set(xlabel="reference (deg)", ylabel="settling time, 2 % band (ms)", title=title)
    ax.legend()
    save_png(plt, fig, path)


def record_plot(path_csv: Path, path: Path) -> None:
    """The recording's signals (u, ω, φ) against time, read back from the CSV just written."""
    from tvsd.recording.csvfile import read

    rec = read(path_csv)
    rows = [("u", rec.u, f"u ({rec.meta.get('u_unit', 'V')})"), ("omega", rec.omega, "ω (rad/s)")]
    if rec.phi_measured:
        rows.append(("phi", rec.phi, "φ (rad)"))
    plt, fig, ax = figure(len(rows), 1, (11, 2.2 * len(rows)))
    for a, (_, y, label) in zip(ax, rows, strict=True):
        a.plot(rec.t, y, lw=0.6)
        a.set_ylabel(label)
    ax[-1].set_xlabel("t (s)")
    fig.suptitle(f"{path_csv.name}: {len(rec.t)} samples at {rec.sample_rate_hz:g} Hz")
    save_png(plt, fig, path)
