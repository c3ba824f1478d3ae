"""Centrality polynomials: regularised least-squares fits over sliding windows.

In each window, time is normalised to tau = (t - c) / h in [-1, 1] (c the window's centre,
h its half-span), which keeps the Vandermonde matrix well conditioned whatever the clock's
origin; coefficients are then solved from the ridge normal equations

    beta = (M^T M + lambda * W * diag(0, 1, ..., 1))^-1 M^T zeta

(W samples in the window; the intercept is not shrunk, it plays no part in derivatives).
A window whose timestamps are all equal gets h = 1 and a flat fit: finite, zero slope.
Derivatives are returned in physical units: d^k zeta / dt^k = h^-k d^k zeta / dtau^k.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view


@dataclass
class Fit:
    """Batched polynomial fits: ``beta`` (windows, degree + 1) in normalised time."""

    beta: np.ndarray
    center: np.ndarray
    half_span: np.ndarray
    tau: np.ndarray  # (windows, W) the samples' normalised times, or (1, W) when shared

    def derivative(self, order: int, tau: np.ndarray | None = None) -> np.ndarray:
        """d^order zeta / dt^order at ``tau`` (default: the samples), physical units."""
        tau = self.tau if tau is None else tau
        coef = self.beta
        for _ in range(order):
            coef = coef[:, 1:] * np.arange(1, coef.shape[1])
        if coef.shape[1] == 0:
            return np.zeros((self.beta.shape[0], tau.shape[-1]))
        return _evaluate(coef, tau) / self.half_span[:, None] ** order

    def value(self, tau: np.ndarray) -> np.ndarray:
        return _evaluate(self.beta, tau)


def _evaluate(coef: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Polynomials (rows of ``coef``) at ``tau`` (windows, W) or shared ``tau`` (1, W)."""
    powers = tau[..., None] ** np.arange(coef.shape[1])
    if tau.shape[0] == 1:
        return coef @ powers[0].T
    return np.einsum("nwk,nk->nw", powers, coef)


def fit_polynomials(
    t: np.ndarray, z: np.ndarray, degree: int = 2, regularization: float = 1e-6
) -> Fit:
    """Fit one polynomial per row of ``t``, ``z`` (shape (windows, W)).

    When every window has the same normalised sample times (a steady frame rate: the usual
    case) one hat matrix serves all windows, and the fit is a single matrix product.
    """
    t = np.atleast_2d(np.asarray(t, dtype=float))
    z = np.atleast_2d(np.asarray(z, dtype=float))
    if t.shape != z.shape:
        raise ValueError(f"t {t.shape} and z {z.shape} differ in shape")
    if degree < 0:
        raise ValueError(f"degree={degree} must be >= 0")
    lo, hi = t.min(axis=1), t.max(axis=1)
    center = (lo + hi) / 2
    half = (hi - lo) / 2
    half = np.where(half > 0, half, 1.0)
    tau = (t - center[:, None]) / half[:, None]
    penalty = np.ones(degree + 1)
    penalty[0] = 0.0
    ridge = regularization * t.shape[1] * np.diag(penalty)
    if np.abs(tau - tau[:1]).max() < 1e-9:  # shared design matrix
        m = tau[0][:, None] ** np.arange(degree + 1)
        a = m.T @ m + ridge
        hat = np.linalg.solve(a, m.T) if regularization > 0 else np.linalg.pinv(a) @ m.T
        return Fit(z @ hat.T, center, half, tau[:1])
    m = tau[..., None] ** np.arange(degree + 1)
    a = np.einsum("nwi,nwj->nij", m, m) + ridge
    b = np.einsum("nwi,nw->ni", m, z)
    if regularization > 0:
        beta = np.linalg.solve(a, b[..., None])[..., 0]
    else:  # plain OLS: the pseudo-inverse keeps degenerate windows finite
        beta = np.einsum("nij,nj->ni", np.linalg.pinv(a), b)
    return Fit(beta, center, half, tau)


def sliding_windows(n: int, window: int, stride: int) -> np.ndarray:
    """Start indices of windows of ``window`` samples every ``stride`` in a run of ``n``.

    A run shorter than a window gives one window over the whole run (if it has >= 2
    samples); the last window is aligned to the run's end so no sample is left out.
    """
    if n < 2:
        return np.zeros(0, dtype=np.int64)
    if n <= window:
        return np.zeros(1, dtype=np.int64)
    starts = np.arange(0, n - window + 1, stride)
    if starts[-1] != n - window:
        starts = np.append(starts, n - window)
    return starts


def window_view(values: np.ndarray, starts: np.ndarray, window: int) -> np.ndarray:
    """(len(starts), window) rows of ``values`` (a view, no copy)."""
    window = min(window, len(values))
    return sliding_window_view(values, window)[starts]
