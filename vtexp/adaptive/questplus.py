"""QUEST+ (Watson 2017) and psi (Kontsevich & Tyler 1999): the posterior over threshold,
slope and lapse, and the level that is expected to teach the most.

The parameters :math:`\\theta = (\\alpha, \\beta, \\lambda)` take values on a grid
(thresholds × slopes × lapses; the guess rate is fixed). For each level :math:`x` of
the stimulus set (the levels the device can play) and each :math:`\\theta`, the
likelihood table :math:`L_{x\\theta} = \\psi(x; \\theta)` is computed once. Then, with
the posterior :math:`\\pi` (a vector over :math:`\\theta`, the prior at first):

- after the answer ``r`` at level ``x`` (Watson 2017, eq. 6):
  :math:`\\pi'_\\theta \\propto \\pi_\\theta L_{x\\theta}` for a yes,
  :math:`\\pi_\\theta (1 - L_{x\\theta})` for a no;
- the next level minimises the expected entropy of the posterior (Watson 2017,
  eqs. 9-13; Kontsevich & Tyler 1999, eqs. 5-8):

  .. math::

      E[H](x) = \\sum_{r \\in \\{0,1\\}} p(r \\mid x)\\, H(\\pi^{(x,r)}), \\qquad
      p(1 \\mid x) = \\sum_\\theta L_{x\\theta}\\,\\pi_\\theta .

Computed as written, that is a pass over the stimulus × parameter table for each
outcome and each level. Expanding :math:`H(\\pi^{(x,r)})` gives, exactly,

.. math::

    E[H](x) = H(\\pi) - \\Big[h\\!\\left(p(1 \\mid x)\\right) - \\sum_\\theta \\pi_\\theta\\, h(L_{x\\theta})\\Big],
    \\qquad h(q) = -q \\log q - (1 - q) \\log(1 - q),

the prior entropy less the mutual information of answer and parameters; with the
table :math:`h(L)` computed once, a trial costs two matrix-vector products
(:math:`L\\pi` and :math:`h(L)\\pi`). ``tests/test_adaptive.py`` checks both the
posterior and :math:`E[H]` against a plain loop over the grid to 1e-9.

The level chosen is the one of least :math:`E[H]` (the lowest on a tie), or, with
``select_among = N``, one of the ``N`` least drawn with vtexp's keyed random stream
(PsychoPy's ``min_n_entropy``). Estimates are the posterior's marginal means (Watson
2017) or its mode.

This is written from the papers; no code of the ``questplus`` package (GPL) is used.

References
----------
Watson, A. B. (2017). QUEST+: A general multidimensional Bayesian adaptive psychometric
method. Journal of Vision, 17(3):10, 1-27.
Kontsevich, L. L., & Tyler, C. W. (1999). Bayesian adaptive estimation of psychometric
slope and threshold. Vision Research, 39(16), 2729-2737.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .psychometric import psi


def xlogy(x, y):
    """x log y, 0 where x is 0 (scipy.special's, imported when a QUEST+ track first
    chooses: every session imports this module, and scipy.special takes a sixth of a
    second to import)."""
    from scipy.special import xlogy as f
    return f(x, y)


def _h(q: np.ndarray) -> np.ndarray:
    """Binary entropy in nats (0 log 0 = 0)."""
    return -xlogy(q, q) - xlogy(1.0 - q, 1.0 - q)


@dataclass(frozen=True)
class QuestPlusRule:
    levels: tuple[float, ...]              # the stimulus set (what the device can play)
    thresholds: tuple[float, ...]
    slopes: tuple[float, ...]
    lapses: tuple[float, ...] = (0.0,)
    guess: float = 0.0
    function: str = "weibull"
    select_among: int = 1                  # 1: the least expected entropy; N: one of the N least
    max_trials: int | None = None


@dataclass
class QuestPlus:
    rule: QuestPlusRule
    n_trials: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        r = self.rule
        a, b, lam = np.meshgrid(np.asarray(r.thresholds, float), np.asarray(r.slopes, float),
                                np.asarray(r.lapses, float), indexing="ij")
        self.params = np.stack([a.ravel(), b.ravel(), lam.ravel()])      # 3 x n_theta
        self.shape = a.shape
        self.levels = np.asarray(r.levels, dtype=float)
        # The likelihood table L[x, theta] and its entropies, once.
        self.L = psi(self.levels[:, None], self.params[0], self.params[1], r.guess,
                     self.params[2], r.function)
        self.hL = _h(self.L)
        self.posterior = np.full(self.params.shape[1], 1.0 / self.params.shape[1])
        self._eh: np.ndarray | None = None

    @property
    def finished(self) -> bool:
        return self.rule.max_trials is not None and self.n_trials >= self.rule.max_trials

    def expected_entropy(self) -> np.ndarray:
        """:math:`E[H](x)` for every level of the stimulus set (nats)."""
        if self._eh is None:
            post = self.posterior
            p1 = self.L @ post
            h_now = -float(xlogy(post, post).sum())
            self._eh = h_now - (_h(p1) - self.hL @ post)
        return self._eh

    def propose(self, rng=None) -> float:
        """The level of least expected entropy; with ``select_among = N``, one of the
        ``N`` least drawn by ``rng`` (an object with ``below(n)``, e.g.
        :class:`vtexp.seeding.HashRandom`)."""
        eh = self.expected_entropy()
        n = min(self.rule.select_among, eh.size)
        if n <= 1 or rng is None:
            return float(self.levels[int(np.argmin(eh))])
        best = np.argsort(eh, kind="stable")[:n]
        return float(self.levels[int(best[rng.below(n)])])

    def index_of(self, level: float) -> int:
        i = int(np.argmin(np.abs(self.levels - level)))
        if not np.isclose(self.levels[i], level, rtol=0, atol=1e-9):
            raise ValueError(f"level {level} is not in the stimulus set")
        return i

    def update(self, level: float, yes: bool) -> None:
        """Bayes' rule with the answer at ``level`` (a level of the stimulus set)."""
        row = self.L[self.index_of(level)]
        post = self.posterior * (row if yes else 1.0 - row)
        self.posterior = post / post.sum()
        self._eh = None
        self.n_trials += 1

    def marginals(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The posterior of threshold, slope and lapse, each summed over the others."""
        p = self.posterior.reshape(self.shape)
        return p.sum(axis=(1, 2)), p.sum(axis=(0, 2)), p.sum(axis=(0, 1))

    def mean(self) -> dict[str, float]:
        """The posterior mean of each parameter (Watson 2017's estimate)."""
        m = self.params @ self.posterior
        return {"threshold": float(m[0]), "slope": float(m[1]), "lapse": float(m[2])}

    def sd(self) -> dict[str, float]:
        """The posterior standard deviation of each parameter."""
        m = self.params @ self.posterior
        v = ((self.params - m[:, None]) ** 2) @ self.posterior
        sd = np.sqrt(np.clip(v, 0.0, None))
        return {"threshold": float(sd[0]), "slope": float(sd[1]), "lapse": float(sd[2])}

    def mode(self) -> dict[str, float]:
        i = int(np.argmax(self.posterior))
        return {"threshold": float(self.params[0, i]), "slope": float(self.params[1, i]),
                "lapse": float(self.params[2, i])}

    def estimate(self) -> float:
        return self.mean()["threshold"]
