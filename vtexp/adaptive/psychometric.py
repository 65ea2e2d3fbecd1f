"""Psychometric functions: the probability of a "yes" (or a correct answer) at a level.

Every function here has the form (Wichmann & Hill 2001, eq. 1)

.. math::

    \\psi(x; \\alpha, \\beta, \\gamma, \\lambda) = \\gamma + (1 - \\gamma - \\lambda)\\,F(x; \\alpha, \\beta)

with ``alpha`` the threshold, ``beta`` the slope, ``gamma`` the guess rate (0 for a
yes/no task, 1/m for m alternatives) and ``lambda`` the lapse rate. The core ``F``:

``weibull``   :math:`F = 1 - \\exp(-(x/\\alpha)^\\beta)`, ``x >= 0`` (Quick 1974; QUEST's
              function, Watson & Pelli 1983 eq. 1, in linear units); ``F(alpha) = 1 - 1/e``.
``logistic``  :math:`F = 1 / (1 + \\exp(-\\beta (x - \\alpha)))`; ``F(alpha) = 1/2``.
``normal``    :math:`F = \\Phi(\\beta (x - \\alpha))` (cumulative normal, ``1/beta`` its SD);
              ``F(alpha) = 1/2``.
``gumbel``    :math:`F = 1 - \\exp(-10^{\\beta (x - \\alpha)/20})` (the log-Weibull of
              Watson & Pelli 1983 with ``x`` in dB); ``F(alpha) = 1 - 1/e``.

Everything broadcasts (numpy), so a whole grid of parameters is evaluated at once.

References
----------
Watson, A. B., & Pelli, D. G. (1983). QUEST: A Bayesian adaptive psychometric method.
Perception & Psychophysics, 33(2), 113-120.
Wichmann, F. A., & Hill, N. J. (2001). The psychometric function: I. Fitting, sampling,
and goodness of fit. Perception & Psychophysics, 63(8), 1293-1313.
"""

from __future__ import annotations

from typing import Literal

import numpy as np


# scipy.special takes a quarter of a second to import, and every session imports this
# module (the scripted responders answer by it): it is imported when a normal function is
# first evaluated.
def ndtr(x):
    from scipy.special import ndtr as f
    return f(x)


def ndtri(p):
    from scipy.special import ndtri as f
    return f(p)


FunctionName = Literal["weibull", "logistic", "normal", "gumbel"]
FUNCTIONS: tuple[str, ...] = ("weibull", "logistic", "normal", "gumbel")


def core(x, threshold, slope, function: str = "weibull") -> np.ndarray:
    """``F(x; alpha, beta)``, from 0 to 1 and increasing in ``x`` (broadcasts)."""
    x = np.asarray(x, dtype=float)
    a = np.asarray(threshold, dtype=float)
    b = np.asarray(slope, dtype=float)
    if function == "weibull":
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.power(np.clip(x, 0.0, None) / a, b)
        return -np.expm1(-z)
    if function == "logistic":
        return 0.5 * (1.0 + np.tanh(0.5 * b * (x - a)))     # overflow-free logistic
    if function == "normal":
        return ndtr(b * (x - a))
    if function == "gumbel":
        return -np.expm1(-np.power(10.0, b * (x - a) / 20.0))
    raise ValueError(f"unknown psychometric function {function!r}; one of {', '.join(FUNCTIONS)}")


def core_and_slopes(x, a, b, function: str = "weibull"):
    """``F(x; a, b)`` as :func:`core` gives it, and its derivatives by ``a`` and by ``b``
    in closed form (the likelihood's gradient in :mod:`.fit`)."""
    if function == "weibull":
        r = np.clip(x, 0.0, None) / a
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.power(r, b)
            log_r = np.where(r > 0, np.log(np.where(r > 0, r, 1.0)), 0.0)
        e = np.exp(-z)
        return -np.expm1(-z), e * (-b * z / a), e * z * log_r
    if function in ("logistic", "normal"):
        u = b * (x - a)
        if function == "logistic":
            f = 0.5 * (1.0 + np.tanh(0.5 * u))
            d = f * (1.0 - f)
        else:
            f = core(x, a, b, "normal")
            d = np.exp(-0.5 * u * u) / np.sqrt(2.0 * np.pi)
        return f, -b * d, (x - a) * d
    if function == "gumbel":
        w = np.power(10.0, b * (x - a) / 20.0)
        d = np.exp(-w) * w * np.log(10.0) / 20.0
        return -np.expm1(-w), -b * d, (x - a) * d
    raise ValueError(f"unknown psychometric function {function!r}")


def psi(x, threshold, slope, guess=0.0, lapse=0.0, function: str = "weibull") -> np.ndarray:
    """The probability of a "yes" (or correct) answer: ``gamma + (1 - gamma - lambda) F``.

    Examples
    --------
    >>> round(float(psi(2.0, 2.0, 3.0, guess=0.5, lapse=0.0)), 4)    # 0.5 + 0.5 (1 - 1/e)
    0.8161
    """
    g = np.asarray(guess, dtype=float)
    lam = np.asarray(lapse, dtype=float)
    return g + (1.0 - g - lam) * core(x, threshold, slope, function)


def threshold_at(p: float, threshold, slope, guess=0.0, lapse=0.0,
                 function: str = "weibull") -> np.ndarray:
    """The level at which ``psi`` equals ``p`` (the inverse of :func:`psi`)."""
    g = np.asarray(guess, dtype=float)
    lam = np.asarray(lapse, dtype=float)
    f = (p - g) / (1.0 - g - lam)
    if np.any((f <= 0) | (f >= 1)):
        raise ValueError(f"psi never reaches {p} with guess {guess} and lapse {lapse}")
    a = np.asarray(threshold, dtype=float)
    b = np.asarray(slope, dtype=float)
    if function == "weibull":
        return a * np.power(-np.log1p(-f), 1.0 / b)
    if function == "logistic":
        return a + np.log(f / (1.0 - f)) / b
    if function == "normal":
        return a + ndtri(f) / b
    if function == "gumbel":
        return a + 20.0 * np.log10(-np.log1p(-f)) / b
    raise ValueError(f"unknown psychometric function {function!r}")
