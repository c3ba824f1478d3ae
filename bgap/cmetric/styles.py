"""Style Likelihood and Intensity Estimates (SLE, SIE) and the aggressiveness score.

Per vehicle and window (see :mod:`bgap.cmetric.poly` for the fits):

============================  ==============================  ==============================
style                         SLE                             SIE
============================  ==============================  ==============================
overtaking / sudden lane       max |d zeta_c / dt|             max |d^2 zeta_c / dt^2|
change
overspeeding                   max |d zeta_d / dt|             max |d^2 zeta_d / dt^2|
weaving                        number of critical points of    largest epsilon-sharpness of
                               zeta_c in the window with       those points
                               epsilon-sharpness > threshold
conservative                   exp(-a_w) (see below)           1 / (1 + max |d^2 zeta_c/dt^2|)
============================  ==============================  ==============================

Maxima are over the window's samples. The epsilon-sharpness of a critical point t_c
(Keskar et al., the paper's ref.) is ``max_{|t - t_c| <= eps} |zeta(t) - zeta(t_c)| /
(1 + |zeta(t_c)|)``, evaluated on the polynomial inside the window.

The **aggressiveness** of a window is ``a_w = sum_k weight_k * SLE_k / scale_k`` over the
three aggressive styles k, and of a vehicle

    A = 1 - exp(-mean_w a_w)      in [0, 1), 0 for a vehicle whose centralities never move.

With the signed ``net_passes`` degree a_w can be negative (the vehicle was passed); then
``A = sign(m) (1 - exp(-|m|))`` with m the aggregate of a_w (the same number when m >= 0),
in (-1, 1): below 0 means more evidence of being passed than of passing. The aggregate over
windows is the mean (the paper's windows, averaged), the maximum (the paper's "maximum
likelihood" read over a vehicle's whole log) or an upper quantile (``cmetric.aggregate``).

The conservative SLE is exp(-a_w), near 1 exactly when the centrality slopes are near 0, as
the paper describes conservative drivers.
"""

from __future__ import annotations

import numpy as np

from bgap.cmetric.poly import Fit

STYLES = ("overtaking", "overspeeding", "weaving")


def critical_points(fit: Fit) -> tuple[np.ndarray, np.ndarray]:
    """Real roots of d zeta / d tau inside (-1, 1): (windows, degree - 1) tau values and a
    validity mask. Companion-matrix eigenvalues, batched over windows."""
    beta = fit.beta
    deriv = beta[:, 1:] * np.arange(1, beta.shape[1])  # coefficients of d zeta / d tau
    n, k = deriv.shape
    if k < 2:
        return np.zeros((n, 0)), np.zeros((n, 0), dtype=bool)
    lead = deriv[:, -1]
    ok = np.abs(lead) > 1e-12 * (np.abs(deriv).max(axis=1) + 1e-300)
    safe = np.where(ok, lead, 1.0)
    if k == 2:  # linear derivative: the common degree-2 case, closed form
        roots = (-deriv[:, 0] / safe)[:, None].astype(complex)
    else:
        comp = np.zeros((n, k - 1, k - 1))
        comp[:, 0, :] = -deriv[:, -2::-1] / safe[:, None]
        comp[:, np.arange(1, k - 1), np.arange(k - 2)] = 1.0
        roots = np.linalg.eigvals(comp)
    real = np.abs(roots.imag) < 1e-9
    tau = roots.real
    valid = ok[:, None] & real & (tau > -1) & (tau < 1)
    return tau, valid


def sharpness(fit: Fit, tau_c: np.ndarray, epsilon: float, points: int = 9) -> np.ndarray:
    """epsilon-sharpness at each critical point (same shape as ``tau_c``)."""
    n, m = tau_c.shape
    if m == 0:
        return np.zeros((n, 0))
    radius = (epsilon / fit.half_span)[:, None, None]
    offsets = np.linspace(-1.0, 1.0, points)[None, None, :] * radius
    grid = np.clip(tau_c[..., None] + offsets, -1.0, 1.0)  # the ball, inside the window
    powers = np.arange(fit.beta.shape[1])
    values = np.einsum("nmgk,nk->nmg", grid[..., None] ** powers, fit.beta)
    at_c = np.einsum("nmk,nk->nm", tau_c[..., None] ** powers, fit.beta)
    return np.abs(values - at_c[..., None]).max(axis=2) / (1.0 + np.abs(at_c))


def window_styles(
    closeness_fit: Fit,
    degree_fit: Fit,
    epsilon: float,
    sharpness_min: float,
    signed_degree: bool = False,
) -> dict[str, np.ndarray]:
    """SLE and SIE of every style for a batch of windows.

    With ``signed_degree`` (the ``net_passes`` degree, which falls when the vehicle is left
    behind) the overspeeding SLE keeps the sign of the slope of largest magnitude: negative
    is evidence of being passed, i.e. of conservative driving.
    """
    d1c = np.abs(closeness_fit.derivative(1))
    d2c = np.abs(closeness_fit.derivative(2))
    tau_c, valid = critical_points(closeness_fit)
    sharp = np.where(valid, sharpness(closeness_fit, tau_c, epsilon), 0.0)
    weaving = valid & (sharp > sharpness_min)
    return {
        "overtaking_sle": d1c.max(axis=1),
        "overtaking_sie": d2c.max(axis=1),
        "overspeeding_sle": _extreme(degree_fit.derivative(1), signed_degree),
        "overspeeding_sie": np.abs(degree_fit.derivative(2)).max(axis=1),
        "weaving_sle": weaving.sum(axis=1).astype(float),
        "weaving_sie": np.where(weaving, sharp, 0.0).max(axis=1, initial=0.0),
        "conservative_sie": 1.0 / (1.0 + d2c.max(axis=1)),
    }


def _extreme(values: np.ndarray, signed: bool) -> np.ndarray:
    """Per row, max |value|; with ``signed``, that value with its sign."""
    magnitude = np.abs(values)
    if not signed:
        return magnitude.max(axis=1)
    return np.take_along_axis(values, magnitude.argmax(axis=1)[:, None], axis=1)[:, 0]


def window_aggressiveness(styles: dict[str, np.ndarray], weights, scales) -> np.ndarray:
    """a_w = sum_k weight_k * SLE_k / scale_k."""
    return sum(getattr(weights, k) * styles[f"{k}_sle"] / getattr(scales, k) for k in STYLES)
