"""The probability of a participant's answers under the model participant.

:class:`ObserverModel` draws an answer from uniforms; this module computes, for
the same model, the probability of every answer a question allows, given what
the device played in the trial. The log-likelihood of a participant's answers
is the sum over their trials and questions of the log of the probability of
the answer they gave. Each step names the equation of :mod:`vtexp.observer.model`
it integrates:

- **choice (M1)**: the evidences ``E_k`` are jointly Gaussian, with means
  ``-s^2 |D_k|^2 / 2`` and covariance ``s^2 D D^T + sigma_d^2 I``. Option ``j`` is
  answered when ``E_j - E_i >= c`` for every other template ``i`` (``c`` the abstain
  criterion, 0 without an abstain option): a multivariate normal orthant of
  K - 1 dimensions, computed by Genz's separation of variables over fixed
  scrambled Sobol points (the same points for every trial and every parameter
  value: common random numbers, so the likelihood is a smooth function of the
  parameters, and exact for two templates). The abstain option takes
  ``1 - sum_j P(j)``.
- **rating (M2)**: ``v`` is Gaussian (the difference of two Gaussian evidences,
  shifted by the bias), so each scale point is the ordered-probit cell between
  two criteria: ``Phi((c_i - mu) / sd) - Phi((c_{i-1} - mu) / sd)``.
- **count**: the winding of the percept plus Gaussian noise, rounded and clipped
  to the question's range: the mass of the normal within half a unit of each
  count, the ends taking the tails.
- **lapse**: with probability ``lapse`` any option (scale point, count) uniformly.

What does not depend on the fitted parameters (the percept of each distinct
played stimulus against the question's templates: ``D D^T``, the winding) is
computed once per :class:`Likelihood`, and shared through the model's cache by
every participant with the same percept parameters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

from ..model import Condition, PlayReport
from .model import ObserverModel, _report_key
from .params import Participant

#: Quasi-Monte-Carlo points of the orthant probabilities (a power of 2). Measured on the
#: duration/SOA study's 32 stimuli against 8,192 points: within 0.0013 of every
#: probability (0.0005 with 256 points, at twice the time).
QMC_POINTS = 128
#: The smallest probability a model answer is given before the lapse mixture (log(0)
#: would make one trial decide a whole fit).
FLOOR = 1e-10

#: The decision parameters and the value each takes unless fitted (from ObserverParams
#: or, for rating_bias, the population's centre).
DECISION = ("efficiency", "decision_noise", "lapse", "abstain_criterion", "rating_step",
            "rating_bias", "turns_sd")


def decision_values(model: ObserverModel) -> dict[str, float]:
    """The decision parameters of the observer file: the values a fit holds fixed."""
    p = model.params
    return {"efficiency": p.efficiency, "decision_noise": p.decision_noise, "lapse": p.lapse,
            "abstain_criterion": p.abstain_criterion, "rating_step": p.rating_step,
            "rating_bias": 0.0, "turns_sd": p.turns_sd}


@dataclass
class Trial:
    """One answer to fit: the question, the trial's condition, what the device played
    (the first play, as the model participant feels it) and the answer given."""

    question: str
    condition: Condition
    played: PlayReport
    answer: str


def _sobol_uniforms(k: int, n: int) -> np.ndarray:
    """n fixed points in [0, 1)^k (scrambled Sobol, a fixed seed: the same in every fit)."""
    from scipy.stats import qmc
    return qmc.Sobol(d=k, scramble=True, seed=20261127).random(n)


class _Choice:
    """The trials of one choice question: probabilities of every option under (M1)."""

    def __init__(self, question, model: ObserverModel, geoms: list, counts: np.ndarray,
                 qmc_points: int):
        spec = model.spec
        self.options = list(question.options)
        self.names = [o for o in self.options if o not in spec.abstain]
        self.cols = [self.options.index(n) for n in self.names]
        ab = [o for o in self.options if o in spec.abstain]
        self.abstain = self.options.index(ab[0]) if ab else None
        self.counts = counts                         # (geometries, options)
        k = self.k = len(self.names)
        self.gram = np.stack([g.gram for g in geoms]) if geoms else np.zeros((0, k, k))
        self.half = np.stack([g.half for g in geoms]) if geoms else np.zeros((0, k))
        self.scale = np.array([g.scale for g in geoms])                    # (G,)
        # For option j: the other templates, whose evidence must trail E_j by c.
        self.others = np.array([[i for i in range(k) if i != j] for j in range(k)], dtype=int)
        # Fixed uniforms (common random numbers) for the separation of variables: one
        # fewer than the dimensions of the orthant, which is K - 1.
        self.w = _sobol_uniforms(max(k - 2, 1), qmc_points)
        # Without an abstain option only the options answered need their probability
        # (the answered templates of each geometry: a participant who is mostly right
        # needs about one of K).
        self.pairs = None
        if self.abstain is None and geoms:
            g, j = np.nonzero(counts[:, self.cols] > 0)
            self.pairs = (g, j)
        self._diffs: dict[bool, tuple] = {}

    def _differences(self, answered: bool) -> tuple:
        """What does not depend on the parameters, for the (geometry g, template j) pairs:
        ``Cov(E_i - E_j)`` without ``s^2`` (its sensory part) and the differences of the
        half squared distances, for every other template ``i``."""
        if answered not in self._diffs:
            if answered:
                g, j = self.pairs
            else:
                g, j = (a.ravel() for a in np.meshgrid(np.arange(len(self.gram)),
                                                       np.arange(self.k), indexing="ij"))
            o = self.others[j]                                             # (P, n)
            Gg = self.gram[g]                                              # (P, K, K)
            rows = np.arange(len(g))[:, None]
            g_oo = Gg[rows[:, :, None], o[:, :, None], o[:, None, :]]      # (P, n, n)
            g_oj = Gg[rows, o, j[:, None]]                                 # (P, n)
            g_jj = Gg[np.arange(len(g)), j, j][:, None, None]
            sensory = g_oo - g_oj[..., :, None] - g_oj[..., None, :] + g_jj
            n = o.shape[1]
            late = np.eye(n) + np.ones((n, n))          # Cov of eta_i - eta_j, per sigma_d^2
            dhalf = self.half[g[:, None], o] - self.half[g, j][:, None]    # (P, n)
            self._diffs[answered] = (g, j, sensory, late, dhalf)
        return self._diffs[answered]

    def _orthants(self, s2, sd, c, answered: bool) -> np.ndarray:
        """P(option j wins by c) for the (geometry g, template j) pairs, per parameter
        vector: (B, P). ``s2``: (B, G) squared scale; ``sd``, ``c``: (B,)."""
        g, j, sensory, late, dhalf = self._differences(answered)
        s2g = s2[:, g]                                                     # (B, P)
        # E_i - E_j = -s^2 (half_i - half_j) + noise, (M1): its covariance and mean
        cov = s2g[..., None, None] * sensory + (sd * sd)[:, None, None, None] * late
        b = -c[:, None, None] + s2g[..., None] * dhalf                     # (B, P, n)
        return _orthant(b, np.linalg.cholesky(cov), self.w)

    def probabilities(self, v: dict[str, np.ndarray], full: bool = False) -> np.ndarray:
        """P(option) for each parameter vector and geometry, before the lapse: (B,
        geometries, options); without an abstain option only of the options answered,
        unless ``full``. ``v``: each decision parameter as an array of B values.

        Option ``j`` is answered when ``E_i - E_j <= -c`` for every other template
        ``i``: a multivariate normal orthant of K - 1 dimensions, computed by Genz's
        separation of variables (Genz 1992, J. Comput. Graph. Stat. 1:141) over fixed
        quasi-random points, exact for two templates and smooth in the parameters.
        """
        n_g, n_o = self.counts.shape
        nb = len(v["lapse"])
        out = np.zeros((nb, n_g, n_o))
        k = self.k
        if k == 0 or (k == 1 and self.abstain is not None):
            out[:, :, self.abstain if self.abstain is not None else 0] = 1.0
            return out
        if k == 1:
            out[:, :, self.cols[0]] = 1.0
            return out
        c = v["abstain_criterion"] if self.abstain is not None else np.zeros(nb)
        sd = np.maximum(v["decision_noise"], 1e-3)
        s2 = (self.scale * self.scale)[None, :] * v["efficiency"][:, None]   # (B, G)
        if self.pairs is not None and not full:
            g, j = self.pairs
            out[:, g, np.asarray(self.cols)[j]] = np.clip(self._orthants(s2, sd, c, True),
                                                          0, 1)
            return out
        pj = self._orthants(s2, sd, c, False).reshape(nb, n_g, k)
        # Not renormalised without an abstain option (they sum to 1 within the quadrature's
        # error, about 1e-3), so that a trial's probability is the same either way.
        if self.abstain is not None:
            out[:, :, self.abstain] = np.clip(1.0 - pj.sum(axis=2), 0.0, 1.0)
        out[:, :, self.cols] = np.clip(pj, 0.0, 1.0)
        return out


def _orthant(b: np.ndarray, L: np.ndarray, w: np.ndarray) -> np.ndarray:
    """P(Y <= b) for Y ~ N(0, L L^T), over the leading axes of ``b`` (..., n) and ``L``
    (..., n, n), by separation of variables over the fixed uniforms ``w`` (Q, >= n - 1).

    Dimension d's conditional mean given the earlier draws is one stacked matrix
    product (``L[d, :d] @ y[:d]`` for every orthant and point at once); the draws are
    kept by dimension so that each step writes and reads contiguous rows.
    """
    n = b.shape[-1]
    lead = b.shape[:-1]
    m = int(np.prod(lead, dtype=np.int64))
    b2 = b.reshape(m, n)
    L2 = L.reshape(m, n, n)
    inv = 1.0 / np.diagonal(L2, axis1=-2, axis2=-1)                        # (M, n)
    e = ndtr(b2[:, 0] * inv[:, 0])                                         # (M,)
    if n == 1:
        return e.reshape(lead)
    q = w.shape[0]
    f = np.repeat(e[:, None], q, axis=1)                                   # (M, Q)
    e = f.copy()
    ys = np.empty((m, n - 1, q))
    wt = np.ascontiguousarray(w.T)
    rows = L2[:, :, None, :]                                               # (M, n, 1, n)
    for d in range(1, n):
        y = ys[:, d - 1]
        np.multiply(wt[d - 1], e, out=y)
        np.maximum(y, 1e-300, out=y)          # w < 1 and e <= 1: only 0 needs a floor
        ndtri(y, out=y)
        mu = np.matmul(rows[:, d, :, :d], ys[:, :d])[:, 0]                 # (M, Q)
        np.subtract(b2[:, d, None], mu, out=e)
        e *= inv[:, d, None]
        ndtr(e, out=e)
        f *= e
    return f.mean(axis=-1).reshape(lead)


class _Rating:
    """The trials of one rating question: ordered-probit cells of (M2)."""

    def __init__(self, question, model: ObserverModel, geoms: list, counts: np.ndarray):
        self.n = len(question.scale)
        self.counts = counts
        g = np.stack([x.gram for x in geoms])                              # (G, 2, 2)
        self.var_xi = g[:, 0, 0] + g[:, 1, 1] - 2 * g[:, 0, 1]             # Var(xi_high - xi_low)
        self.dhalf = np.array([x.half[1] - x.half[0] for x in geoms])
        self.scale = np.array([x.scale for x in geoms])
        self.spread = np.array([x.spread for x in geoms])

    def probabilities(self, v: dict[str, np.ndarray], full: bool = False) -> np.ndarray:
        s = self.scale[None, :] * np.sqrt(v["efficiency"])[:, None]       # (B, G)
        mean = -s * s * self.dhalf                                         # E_high - E_low
        var = s * s * self.var_xi + 2 * (v["decision_noise"] ** 2)[:, None]
        d = s * self.spread
        d = np.where(d > 1e-12, d, 1.0)                                    # as the model divides
        mu = mean / d + v["rating_bias"][:, None]                          # (M2)
        sd = np.maximum(np.sqrt(var) / d, 1e-9)
        cuts = (np.arange(self.n - 1) - (self.n - 2) / 2)[None, :] * v["rating_step"][:, None]
        cdf = ndtr((cuts[:, None, :] - mu[..., None]) / sd[..., None])     # (B, G, n - 1)
        edge = np.zeros((*mu.shape, 1))
        return np.diff(np.concatenate([edge, cdf, edge + 1.0], axis=2), axis=2)


class _Count:
    """The trials of one number question: a Gaussian count, rounded and clipped."""

    def __init__(self, question, model: ObserverModel, geoms: list, counts: np.ndarray):
        self.lo, self.hi = question.minimum, question.maximum
        self.counts = counts
        self.turns = np.array([g.turns for g in geoms])

    def probabilities(self, v: dict[str, np.ndarray], full: bool = False) -> np.ndarray:
        sd = np.maximum(v["turns_sd"], 1e-6)                                # (B,)
        edges = np.arange(self.lo, self.hi) + 0.5                           # between counts
        cdf = ndtr((edges[None, None, :] - self.turns[None, :, None]) / sd[:, None, None])
        edge = np.zeros((len(sd), len(self.turns), 1))
        return np.diff(np.concatenate([edge, cdf, edge + 1.0], axis=2), axis=2)


class Likelihood:
    """The log-likelihood of one participant's answers, as a function of the decision
    parameters (:data:`DECISION`); the percept parameters are ``who``'s.

    ``trials`` with the same question and the same played stimulus share one
    geometry; answers that are not an option of their question are counted in
    ``unknown`` and left out.
    """

    def __init__(self, model: ObserverModel, who: Participant, trials: list[Trial], *,
                 qmc_points: int = QMC_POINTS):
        questions = {q.name: q for q in model.lx.experiment.asked()}
        groups: dict[str, dict[tuple, tuple]] = {}
        self.unknown = 0
        self.n = 0
        for t in trials:
            q = questions[t.question]
            key = (t.condition.index, _report_key(t.played))
            per_q = groups.setdefault(q.name, {})
            if key not in per_q:
                per_q[key] = (t.condition, t.played, [])
            per_q[key][2].append(t.answer)
        self.parts: list = []
        #: per part (question), the condition index of each of its geometries, in order
        self.conditions: list[list[int]] = []
        #: per part, the question's name
        self.questions: list[str] = []
        for name, per_q in groups.items():
            q = questions[name]
            opts = _answer_options(q)
            index = {o: i for i, o in enumerate(opts)}
            geoms, rows = [], []
            for (ci, pkey), (cond, played, answers) in per_q.items():
                row = np.zeros(len(opts))
                for a in answers:
                    i = index.get(_normal_answer(q, a))
                    if i is None:
                        self.unknown += 1
                    else:
                        row[i] += 1
                        self.n += 1
                geoms.append(model.geometry(q, cond, played, who, ("played", ci, pkey)))
                rows.append(row)
            counts = np.array(rows)
            if q.kind == "choice":
                part = _Choice(q, model, geoms, counts, qmc_points)
            elif q.kind == "rating":
                part = _Rating(q, model, geoms, counts)
            else:
                part = _Count(q, model, geoms, counts)
            self.parts.append(part)
            self.conditions.append([ci for ci, _ in per_q])
            self.questions.append(name)
        self.kinds = {questions[n].kind for n in groups}

    def probabilities(self, values: dict[str, float], full: bool = True) -> list[np.ndarray]:
        """Per question: P(answer) of every geometry and option, lapses included (with
        ``full=False``, only of the answers given: the others are left at the floor)."""
        return [p[0] for p in self._probabilities(batch_values([values]), full)]

    def _probabilities(self, v: dict[str, np.ndarray], full: bool) -> list[np.ndarray]:
        lapse = v["lapse"][:, None, None]
        out = []
        for part in self.parts:
            p = np.maximum(part.probabilities(v, full), FLOOR)
            out.append((1.0 - lapse) * p + lapse / p.shape[2])
        return out

    def __call__(self, values: dict[str, float]) -> float:
        return float(self.batch(batch_values([values]))[0])

    def batch(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """The log-likelihood at B parameter vectors at once (each decision parameter an
        array of B values, :func:`batch_values`): (B,). One call costs little more than
        one vector's, since the arrays of a participant are small: a fit's finite
        differences and scans are evaluated together."""
        total = np.zeros(len(values["lapse"]))
        for part, p in zip(self.parts, self._probabilities(values, full=False), strict=True):
            total += (part.counts[None] * np.log(p)).sum(axis=(1, 2))
        return total


def batch_values(vectors: list[dict[str, float]]) -> dict[str, np.ndarray]:
    """Parameter vectors (dicts of the decision parameters) as one array per parameter."""
    return {n: np.array([float(v[n]) for v in vectors]) for n in DECISION}


def _answer_options(q) -> list[str]:
    if q.kind == "choice":
        return list(q.options)
    if q.kind == "rating":
        return [str(v) for v in q.scale]
    return [str(v) for v in range(q.minimum, q.maximum + 1)]


def _normal_answer(q, a) -> str:
    """An answer as the log holds it, in the form of :func:`_answer_options` ("2.0" -> "2")."""
    a = str(a).strip()
    if q.kind != "choice":
        try:
            f = float(a)
        except ValueError:
            return a
        if f == int(f):
            return str(int(f))
    return a
