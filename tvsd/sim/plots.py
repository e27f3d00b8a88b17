"""Figures for `tvsctl sim --plot FILE.png` (matplotlib, no display needed)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.errors import UsageError
from tvsd.sim.runs import Trace


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


def step_plot(trace: Trace, ref_rad: float, title: str, path: Path) -> None:
    """Phase portrait, position and velocity (the paper's Figs. 14–16)."""
    plt, fig, ax = figure(1, 3, (13, 3.8))
    ax[0].plot(trace.phi, trace.omega, lw=1)
    ax[0].plot([ref_rad], [0], "k+", ms=12)
    ax[0].set(xlabel="φ (rad)", ylabel="ω (rad/s)", title="phase portrait")
    ax[1].plot(trace.t, np.degrees(trace.phi), lw=1)
    ax[1].axhline(math.degrees(ref_rad), color="k", lw=0.8, ls="--")
    ax[1].axhspan(math.degrees(ref_rad) * 0.98, math.degrees(ref_rad) * 1.02, color="0.9")
    ax[1].set(xlabel="t (s)", ylabel="φ (deg)", title="position")
    ax[2].plot(trace.t, trace.omega, lw=1)
    ax[2].set(xlabel="t (s)", ylabel="ω (rad/s)", title="velocity")
    fig.suptitle(title)
    save_png(plt, fig, path)


def spin_plot(
    trace: Trace,
    rps: float,
    steady_from: float,
    spectrum: tuple[np.ndarray, np.ndarray],
    dominant_hz: float,
    title: str,
    path: Path,
) -> None:
    plt, fig, ax = figure(1, 2, (12, 4))
    ax[0].plot(trace.t, trace.omega_mean / (2 * math.pi), lw=0.8)
    ax[0].axhline(rps, color="k", lw=0.8, ls="--")
    ax[0].axvline(steady_from, color="0.6", lw=0.8, ls=":")
    ax[0].set(xlabel="t (s)", ylabel="speed (rev/s)", title="scanning-aperture speed")
    f, amp = spectrum
    ax[1].semilogy(f, amp, lw=0.8)
    ax[1].axvline(dominant_hz, color="r", lw=0.8, ls=":", label=f"dominant {dominant_hz:.2f} Hz")
    ax[1].axvline(rps, color="k", lw=0.8, ls="--", label=f"rotation {rps:g} Hz")
    ax[1].set(
        xlabel="frequency (Hz)",
        ylabel="amplitude (rad/s²)",
        title="SA vibration spectrum",
        xlim=(0, min(200, f[-1])),
    )
    ax[1].legend()
    fig.suptitle(title)
    save_png(plt, fig, path)
