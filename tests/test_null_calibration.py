"""The decision's null noise model (tvsd.analysis.calibrate.null_gram): the covariance of a block's
projection on noise with the whitened residual's own spectrum.

Tolerances from the estimator's statistics: each spectral level is the median of a block of 21
periodogram ordinates over ln 2, relative standard deviation ≈ 1.25/√21 = 0.27 per block; a
broadband column averages ≈ 95 blocks (n = 4000); the level is floored at the flat one, so its
variance ratio is 1 + E[(S − 1)₊] ≈ 1.11 ± 0.02 and [1, 1.25] is > 5σ; a column below 3 Hz
(of 125) spans ~2 blocks (± 0.2), so the coloured check allows 0.6–1.5 where the i.i.d. null's
ratio is 1/3 — the test fails if the spectrum is ignored.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from tvsd.analysis.calibrate import null_gram, residual_spectrum


def test_white_residual_gives_the_iid_gram():
    rng = np.random.default_rng(3)
    n = 4000
    G = rng.standard_normal((n, 4))
    e = rng.standard_normal(n)
    ratio = np.diag(null_gram(G, e)) / np.diag(G.T @ G)
    assert np.all((ratio >= 1.0 - 1e-9) & (ratio < 1.25)), ratio
    assert float(np.min(residual_spectrum(e))) >= 1.0  # never narrower than the AR model's null


def test_coloured_residual_sets_the_projection_variance():
    """AR(1), φ = 0.5: the spectrum at low frequency is (1 + φ)/(1 − φ) = 3× its mean, so a
    slow column's projection varies 3× more than GᵀG says; null_gram must see it."""
    rng = np.random.default_rng(5)
    n, phi, fs = 4000, 0.5, 250.0
    e = lfilter([1.0], [1.0, -phi], rng.standard_normal(n))
    t = np.arange(n) / fs
    g = np.sin(2 * np.pi * 0.7 * t) + 0.5 * np.sin(2 * np.pi * 2.1 * t + 1.0)  # below 3 Hz
    # Var(gᵀε) = Σ_k γ(k)·Σ_i g_i·g_(i+k), γ(k) = φ^|k| at unit variance (the null's scale is
    # the residual's own)
    lags = np.arange(-(n - 1), n)
    true = float(np.correlate(g, g, "full") @ phi ** np.abs(lags))
    est = float(null_gram(g[:, None], e)[0, 0])
    assert 0.6 < est / true < 1.5, (est, true, float(g @ g))
    assert float(g @ g) / true < 0.45  # the i.i.d. null would be ≈ 1/3 of it
