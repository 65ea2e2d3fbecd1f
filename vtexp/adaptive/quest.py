"""QUEST: a Bayesian adaptive estimate of a threshold (Watson & Pelli 1983).

The threshold :math:`\\alpha` is unknown; its posterior is kept on a grid
:math:`\\alpha_1..\\alpha_m`. Before any trial it is the prior (a normal density of
the declared mean and SD, or flat; Watson & Pelli 1983, eq. 5). After the answers
:math:`r_1..r_n` (1 yes, 0 no) at levels :math:`x_1..x_n` (eq. 6):

.. math::

    \\log p(\\alpha \\mid r) = \\log p(\\alpha)
        + \\sum_k r_k \\log \\psi(x_k; \\alpha) + (1 - r_k) \\log(1 - \\psi(x_k; \\alpha))
        + \\text{const}

with the psychometric function :math:`\\psi` of :mod:`.psychometric` (slope, guess and
lapse fixed: QUEST estimates the threshold alone). The next level is the posterior's
mode (Watson & Pelli's choice), mean (King-Smith et al. 1994) or median, placed where
:math:`\\psi` reaches ``target`` if one is given, then moved to the nearest level the
device can play. The log posterior is kept, so a long run loses no precision.

References
----------
Watson, A. B., & Pelli, D. G. (1983). QUEST: A Bayesian adaptive psychometric method.
Perception & Psychophysics, 33(2), 113-120.
King-Smith, P. E., Grigsby, S. S., Vingrys, A. J., Benes, S. C., & Supowit, A. (1994).
Efficient and unbiased modifications of the QUEST threshold method. Vision Research,
34(7), 885-912.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .psychometric import psi, threshold_at


@dataclass(frozen=True)
class QuestRule:
    thresholds: tuple[float, ...]          # the grid of alpha
    slope: float
    guess: float = 0.0
    lapse: float = 0.01
    function: str = "weibull"
    prior_mean: float | None = None        # None: a flat prior
    prior_sd: float | None = None
    method: str = "mean"                   # "mode", "mean" or "median" of the posterior
    target: float | None = None            # place trials where psi = target (None: at alpha)
    max_trials: int | None = None


@dataclass
class Quest:
    rule: QuestRule
    n_trials: int = field(default=0, init=False)
    log_post: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        a = np.asarray(self.rule.thresholds, dtype=float)
        self._alpha = a
        if self.rule.prior_mean is None:
            self.log_post = np.zeros_like(a)
        else:
            self.log_post = -0.5 * ((a - self.rule.prior_mean) / self.rule.prior_sd) ** 2

    @property
    def finished(self) -> bool:
        return self.rule.max_trials is not None and self.n_trials >= self.rule.max_trials

    def posterior(self) -> np.ndarray:
        """The normalised posterior over the threshold grid."""
        p = np.exp(self.log_post - self.log_post.max())
        return p / p.sum()

    def threshold(self, method: str | None = None) -> float:
        """The posterior's mode, mean or median."""
        method = method or self.rule.method
        p = self.posterior()
        if method == "mode":
            return float(self._alpha[int(np.argmax(p))])
        if method == "mean":
            return float(p @ self._alpha)
        if method == "median":
            return float(self._alpha[int(np.searchsorted(np.cumsum(p), 0.5))])
        raise ValueError(f"unknown QUEST method {method!r}")

    def propose(self) -> float:
        a = self.threshold()
        r = self.rule
        if r.target is None:
            return a
        return float(threshold_at(r.target, a, r.slope, r.guess, r.lapse, r.function))

    def update(self, level: float, yes: bool) -> None:
        r = self.rule
        p = psi(level, self._alpha, r.slope, r.guess, r.lapse, r.function)
        p = np.clip(p if yes else 1.0 - p, 1e-300, None)
        self.log_post = self.log_post + np.log(p)
        self.n_trials += 1

    def estimate(self) -> float:
        return self.threshold("mean")

    def sd(self) -> float:
        """The posterior's standard deviation of the threshold (on the grid)."""
        p = self.posterior()
        m = float(p @ self._alpha)
        return float(np.sqrt(max(float(p @ (self._alpha - m) ** 2), 0.0)))
