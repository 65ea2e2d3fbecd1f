"""Trial-level mixed-effects logistic regression of correct/incorrect on the factors.

The modern alternative to an ANOVA on recognition rates (Jaeger 2008): every
trial enters as a Bernoulli outcome, participants (and, where declared, items)
differ by random intercepts, and rates near 0 or 1 are not squeezed.

Method: maximum likelihood as ``lme4::glmer``
---------------------------------------------
The model is ``logit P(correct) = X β + Σ_k θ_k u_k[group]`` with spherical
random effects ``u ~ N(0, I)`` and ``θ_k`` the SD of term ``k`` (Bates et al.
2015, eqs. 2–5). For given ``(θ, β)`` the conditional mode ``u*`` maximises
``Σ log p(y | u) − |u|²/2`` (penalised iteratively reweighted least squares,
Newton steps with step halving); then

- **Laplace** (``nAGQ = 1``, any number of random-intercept terms, crossed
  participants and items included): deviance ``−2 Σ log p(y | u*) + |u*|² +
  log det(I + Λ Zᵀ W Z Λ)`` (Bates et al. 2015, eq. 31; Pinheiro & Bates
  1995);
- **adaptive Gauss–Hermite quadrature** (``n_quad > 1``, one random-intercept
  term, as ``glmer(nAGQ = n)``): each participant's integral over their
  intercept evaluated at ``n`` nodes centred on their mode and scaled by its
  curvature (Liu & Pierce 1994; Pinheiro & Bates 1995, §3).

The deviance is minimised over ``(θ ≥ 0, β)`` by L-BFGS-B from fixed starting
values (the logistic regression without random effects, θ = 1), then polished
with Newton steps on a finite-difference Hessian: no random numbers anywhere,
so a fit is the same on every run. Standard errors are defined as ``vcov()``
defines them for a ``glmer`` fit: twice the inverse of the deviance's Hessian in
``(θ, β)``, the β block (lme4's ``use.hessian = TRUE``), so they include the
uncertainty of θ. They are not glmer's numbers to the last digit: each Hessian is
taken by finite differences, here of this module's deviance at this module's
optimum and in lme4 by its own difference scheme at its own optimum, and the Laplace
deviance is flat enough in θ that the two differ slightly. On the reference fits
(``tests/test_glmm_reference.py``: four data sets, one near the ceiling, fhch2010,
98 % correct) the SEs differ from glmer's by at most 0.9 % under the Laplace
approximation (crossed items the most) and by less than 0.01 % with quadrature
(nAGQ 9 and 25); the test allows 1 %. Estimates agree within 1 % of an SE.

A fit whose gradient does not vanish, whose Hessian is not positive definite,
or whose estimates run off to infinity (complete separation: every answer
correct in a condition) is reported by a :class:`MixedModelWarning` that says
which and what to do, or refused (``on_failure="error"``).
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pandas as pd
from scipy import optimize, stats

from ..errors import InputError

__all__ = ["mixed_logit", "MixedModelWarning", "glmm_deviance"]

Z95 = 1.959963984540054
SEPARATION_SE = 5.0        # log-odds: an SE this large means the estimate has no finite optimum


class MixedModelWarning(UserWarning):
    """A mixed logistic model did not converge or its estimates are not to be trusted."""


def _levels(col: pd.Series) -> list[str]:
    present = set(col.dropna().astype(str))
    if isinstance(col.dtype, pd.CategoricalDtype):
        return [str(x) for x in col.cat.categories if str(x) in present]
    return sorted(present)


def _design(d: pd.DataFrame, factors: list[str], interactions: bool):
    """Treatment-coded X (first level the reference), its column names, the levels."""
    cols = [np.ones(len(d))]
    names = ["Intercept"]
    dummies: dict[str, list[tuple[str, np.ndarray]]] = {}
    levels = {}
    for f in factors:
        lv = _levels(d[f])
        if len(lv) < 2:
            raise InputError(f"factor {f!r} has only {len(lv)} level(s) among the scored trials")
        levels[f] = lv
        s = d[f].astype(str).to_numpy()
        dummies[f] = [(f"{f}[{v}]", (s == v).astype(float)) for v in lv[1:]]
    orders = range(1, len(factors) + 1) if interactions else [1]
    for r in orders:
        for combo in itertools.combinations(factors, r):
            for parts in itertools.product(*(dummies[f] for f in combo)):
                names.append(":".join(n for n, _ in parts))
                cols.append(np.prod([c for _, c in parts], axis=0))
    X = np.column_stack(cols)
    rank = np.linalg.matrix_rank(X)
    if rank < X.shape[1]:
        raise InputError(f"the fixed effects {', '.join(names)} cannot all be estimated "
                         f"(rank {rank} of {X.shape[1]}): some combination of levels has no "
                         "scored trial")
    return X, names, levels


class _Model:
    """Bernoulli GLMM with random intercepts; deviance as lme4 defines it."""

    def __init__(self, X: np.ndarray, y: np.ndarray, groups: list[np.ndarray]):
        self.X, self.y = X, y
        self.groups = groups
        self.q = [int(g.max()) + 1 for g in groups]
        self.offsets = np.concatenate([[0], np.cumsum(self.q)])
        self.u = np.zeros(int(sum(self.q)))

    # -- conditional mode --------------------------------------------------------------
    def _eta(self, beta, theta, u):
        eta = self.X @ beta
        for k, g in enumerate(self.groups):
            eta = eta + theta[k] * u[self.offsets[k]:self.offsets[k + 1]][g]
        return eta

    def _penalised(self, beta, theta, u):
        eta = self._eta(beta, theta, u)
        return float((self.y * eta - np.logaddexp(0, eta)).sum() - 0.5 * u @ u), eta

    def _grad_hess(self, theta, eta, u):
        """Gradient of log p(y, u) in u, and the negative Hessian ``I + Λ Zᵀ W Z Λ``.

        One term: the Hessian is diagonal. Two crossed terms (participants and
        items): ``[[D1, B], [Bᵀ, D2]]`` with diagonal blocks, kept as such and
        solved through the Schur complement of ``D2`` (q1 × q1).
        """
        mu = 1 / (1 + np.exp(-eta))
        r = self.y - mu
        w = mu * (1 - mu)
        g = -u.copy()
        diags = []
        for k, gi in enumerate(self.groups):
            o = self.offsets[k]
            g[o:o + self.q[k]] += theta[k] * np.bincount(gi, weights=r, minlength=self.q[k])
            diags.append(theta[k] ** 2 * np.bincount(gi, weights=w, minlength=self.q[k]) + 1.0)
        if len(self.groups) == 1:
            return g, ("diag", diags[0])
        g1, g2 = self.groups
        q1, q2 = self.q
        B = np.bincount(g1 * q2 + g2, weights=w, minlength=q1 * q2).reshape(q1, q2)
        B *= theta[0] * theta[1]
        return g, ("two", diags[0], diags[1], B)

    def _solve(self, H, g):
        if H[0] == "diag":
            return g / H[1]
        _, d1, d2, B = H
        q1 = len(d1)
        S = np.diag(d1) - (B / d2) @ B.T
        a = np.linalg.solve(S, g[:q1] - B @ (g[q1:] / d2))
        b = (g[q1:] - B.T @ a) / d2
        return np.concatenate([a, b])

    def _logdet(self, H):
        if H[0] == "diag":
            return float(np.log(H[1]).sum())
        _, d1, d2, B = H
        S = np.diag(d1) - (B / d2) @ B.T
        return float(np.log(d2).sum() + np.linalg.slogdet(S)[1])

    def mode(self, beta, theta, u=None, tol=1e-12, max_iter=100):
        """u*, the linear predictor there, and the Hessian of −log p(y, u) at u*."""
        u = self.u.copy() if u is None else u.copy()
        f, eta = self._penalised(beta, theta, u)
        for _ in range(max_iter):
            g, H = self._grad_hess(theta, eta, u)
            step = self._solve(H, g)
            dec = float(g @ step)
            t = 1.0
            while True:
                u_new = u + t * step
                f_new, eta_new = self._penalised(beta, theta, u_new)
                if f_new >= f - 1e-12 * abs(f) or t < 1e-10:
                    break
                t /= 2
            u, f, eta = u_new, f_new, eta_new
            if dec < tol:
                break
        g, H = self._grad_hess(theta, eta, u)
        return u, eta, H

    # -- deviance ----------------------------------------------------------------------
    def deviance(self, params, n_quad: int = 1) -> float:
        k = len(self.groups)
        theta, beta = np.abs(params[:k]), params[k:]
        u, eta, H = self.mode(beta, theta)
        self.u = u
        loglik = float((self.y * eta - np.logaddexp(0, eta)).sum())
        if n_quad <= 1:
            return -2 * loglik + float(u @ u) + self._logdet(H)
        return self._aghq(beta, theta[0], u, H[1], n_quad)

    def _aghq(self, beta, theta, u, h, n_quad):
        """−2 log likelihood by adaptive Gauss–Hermite quadrature (one intercept term)."""
        z, w = np.polynomial.hermite.hermgauss(n_quad)
        gi = self.groups[0]
        xb = self.X @ beta
        sigma = 1 / np.sqrt(h)
        total = np.zeros(len(u))
        logs = []
        for zk in z:
            uk = u + np.sqrt(2) * sigma * zk
            eta = xb + theta * uk[gi]
            ll = np.bincount(gi, weights=self.y * eta - np.logaddexp(0, eta),
                             minlength=len(u))
            logs.append(ll - uk ** 2 / 2 + zk ** 2)
        L = np.array(logs)                                  # nodes × groups
        m = L.max(axis=0)
        total = m + np.log((w[:, None] * np.exp(L - m)).sum(axis=0))
        total += np.log(np.sqrt(2) * sigma) - 0.5 * np.log(2 * np.pi)
        return float(-2 * total.sum())


def glmm_deviance(model: _Model, params: np.ndarray, n_quad: int = 1) -> float:
    """The deviance of ``model`` at ``params`` = (θ..., β...) (for tests and benchmarks)."""
    return model.deviance(np.asarray(params, dtype=float), n_quad)


def _fd_grad_hess(f, x, h):
    """Central finite-difference gradient and Hessian (steps ``h`` per coordinate)."""
    n = len(x)
    f0 = f(x)
    g = np.zeros(n)
    H = np.zeros((n, n))
    E = np.diag(h)
    fp = [f(x + E[i]) for i in range(n)]
    fm = [f(x - E[i]) for i in range(n)]
    for i in range(n):
        g[i] = (fp[i] - fm[i]) / (2 * h[i])
        H[i, i] = (fp[i] - 2 * f0 + fm[i]) / h[i] ** 2
    for i in range(n):
        for j in range(i + 1, n):
            v = (f(x + E[i] + E[j]) - f(x + E[i] - E[j]) - f(x - E[i] + E[j])
                 + f(x - E[i] - E[j])) / (4 * h[i] * h[j])
            H[i, j] = H[j, i] = v
    return f0, g, H


def _logistic_start(X, y):
    """β of the logistic regression without random effects (a few IRLS steps, bounded)."""
    beta = np.zeros(X.shape[1])
    for _ in range(25):
        eta = np.clip(X @ beta, -20, 20)
        mu = 1 / (1 + np.exp(-eta))
        w = np.maximum(mu * (1 - mu), 1e-6)
        step = np.linalg.lstsq(X * np.sqrt(w)[:, None], (y - mu) / np.sqrt(w), rcond=None)[0]
        beta = np.clip(beta + step, -15, 15)
        if np.abs(step).max() < 1e-8:
            break
    return beta


def mixed_logit(trials: pd.DataFrame, factors: list[str] | str, *, outcome: str = "correct",
                subject: str = "participant", items: str | None = None,
                interactions: bool = False, n_quad: int = 1,
                on_failure: str = "warn") -> pd.DataFrame:
    """Mixed logistic regression by maximum likelihood, as ``lme4::glmer``.

    ``outcome ~ factors + (1 | subject) [+ (1 | items)]``, binomial family,
    logit link; see the module docstring for the method.

    Parameters
    ----------
    trials : tidy trial table; rows with a missing ``outcome`` (unscored) are left out.
    factors : categorical predictors, treatment-coded against their first level
        (the first declared level, or the first in sorted order).
    subject : the participants' column (random intercept).
    items : a column of stimulus items for a crossed random intercept (e.g. the
        letter or picture shown), or None.
    interactions : include all interactions of the factors (default: main effects).
    n_quad : 1 = Laplace approximation (glmer's default); more = adaptive
        Gauss–Hermite quadrature with that many nodes (``nAGQ``), only with no
        ``items`` term (as glmer).
    on_failure : ``"warn"`` (a :class:`MixedModelWarning` naming the problem,
        and ``attrs["problems"]``) or ``"error"`` (:class:`InputError`).

    Returns
    -------
    DataFrame, one row per fixed-effect term (``Intercept`` first): ``term``,
    ``estimate`` (log-odds), ``se``, ``z``, ``p`` (Wald), ``ci_low``,
    ``ci_high`` (Wald 95 %), ``odds_ratio``; then one row per random term,
    ``sd(subject)`` (and ``sd(items)``), with the SD as ``estimate``. ``attrs``:
    ``method``, ``formula``, ``deviance``, ``n_trials``, ``n_participants``,
    ``reference_levels``, ``converged``, ``problems``, ``gradient``.

    References
    ----------
    Bates, Mächler, Bolker & Walker (2015), Fitting linear mixed-effects models
    using lme4, J. Stat. Softw. 67(1), eqs. 2–5 and 31 (the Laplace deviance);
    Pinheiro & Bates (1995), J. Comput. Graph. Stat. 4(1) (adaptive quadrature);
    Jaeger (2008), J. Mem. Lang. 59 (why trials, not rates).
    """
    factors = [factors] if isinstance(factors, str) else list(factors)
    if on_failure not in ("warn", "error"):
        raise InputError(f"on_failure must be 'warn' or 'error', not {on_failure!r}")
    re_cols = [subject] + ([items] if items else [])
    missing = [c for c in [outcome, *re_cols, *factors] if c not in trials.columns]
    if missing:
        raise InputError(f"no column(s) {', '.join(map(repr, missing))} in the trial table")
    if n_quad < 1 or (n_quad > 1 and items):
        raise InputError("adaptive quadrature (n_quad > 1) needs exactly one random term "
                         "(no items), as in glmer; use n_quad = 1 (Laplace)")
    d = trials[[outcome, *re_cols, *factors]]
    d = d[d[outcome].notna()]
    if d.empty:
        raise InputError(f"no trials with a value of {outcome!r}")
    y = pd.to_numeric(d[outcome], errors="coerce")
    if not y.isin([0, 1]).all():
        raise InputError(f"{outcome!r} must be 0 or 1 on every scored trial")
    y = y.to_numpy(dtype=float)
    X, names, levels = _design(d, factors, interactions)
    groups = []
    for c in re_cols:
        codes, uniq = pd.factorize(d[c].astype(str), sort=True)
        if len(uniq) < 2:
            raise InputError(f"{c!r} has {len(uniq)} level(s); a random intercept needs several")
        groups.append(codes.astype(np.int64))
    model = _Model(X, y, groups)
    k = len(groups)

    def dev(x):
        return model.deviance(x, n_quad)

    x0 = np.concatenate([np.ones(k), _logistic_start(X, y)])
    bounds = [(0.0, None)] * k + [(None, None)] * X.shape[1]
    res = optimize.minimize(dev, x0, method="L-BFGS-B", bounds=bounds,
                            options={"maxiter": 2000, "ftol": 1e-15, "gtol": 1e-7,
                                     "maxcor": 20})
    x = res.x.copy()
    # Newton polish on the finite-difference Hessian (the optimiser stops at ~1e-5)
    problems: list[str] = []
    for _ in range(6):
        h = 1e-3 * np.maximum(1.0, np.abs(x))
        f0, g, H = _fd_grad_hess(dev, x, h)
        try:
            step = np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)):
            break
        x_new = x - step
        x_new[:k] = np.maximum(x_new[:k], 0.0)
        if dev(x_new) <= f0 + 1e-9:
            x = x_new
        if np.abs(step).max() < 1e-7:
            break
    h = 1e-3 * np.maximum(1.0, np.abs(x))
    f0, g, H = _fd_grad_hess(dev, x, h)
    boundary = [i for i in range(k) if x[i] < 1e-4]
    free = [i for i in range(len(x)) if i not in boundary]
    Hf = H[np.ix_(free, free)]
    eig = np.linalg.eigvalsh(Hf)
    grad_free = g[free]
    if not (eig > 0).all():
        problems.append("the deviance's Hessian is not positive definite at the estimates "
                        f"(smallest eigenvalue {eig.min():.3g}): the fit did not converge to "
                        "a maximum")
        cov = np.full((len(x), len(x)), np.nan)
    else:
        cov = np.full((len(x), len(x)), np.nan)
        cov[np.ix_(free, free)] = 2 * np.linalg.inv(Hf)
        scaled = np.abs(np.linalg.solve(Hf, grad_free)).max()
        if scaled > 1e-3:
            problems.append(f"the fit did not converge: the scaled gradient is {scaled:.2g} "
                            "(lme4's check: < 0.001)")
    se = np.sqrt(np.diag(cov))[k:]
    beta = x[k:]
    for name, b, s in zip(names, beta, se):
        if not np.isfinite(s) or s > SEPARATION_SE:
            problems.append(f"the estimate of {name} ({b:.3g} log-odds, SE {s:.3g}) has no "
                            "finite maximum: its trials are (quasi-)completely separated, e.g. "
                            "every answer correct in a condition; merge or drop that condition, "
                            "or report its rate without a model")
    for i in boundary:
        problems.append(f"the SD of the random intercept of {re_cols[i]!r} is estimated as 0 "
                        "(a singular fit): the model cannot tell the "
                        f"{re_cols[i]}s apart; the fixed effects are those of a model without "
                        "that term")
    rows = []
    for name, b, s in zip(names, beta, se):
        z = b / s if s > 0 else np.nan
        rows.append({"term": name, "estimate": b, "se": s, "z": z,
                     "p": 2 * stats.norm.sf(abs(z)) if np.isfinite(z) else np.nan,
                     "ci_low": b - Z95 * s, "ci_high": b + Z95 * s, "odds_ratio": np.exp(b)})
    for i, c in enumerate(re_cols):
        rows.append({"term": f"sd({c})", "estimate": float(x[i]), "se": np.nan, "z": np.nan,
                     "p": np.nan, "ci_low": np.nan, "ci_high": np.nan, "odds_ratio": np.nan})
    out = pd.DataFrame(rows)
    rhs = (" * " if interactions else " + ").join(factors) or "1"
    method = ("maximum likelihood, Laplace approximation (as lme4::glmer, nAGQ = 1)"
              if n_quad == 1 else
              f"maximum likelihood, adaptive Gauss–Hermite quadrature with {n_quad} nodes "
              f"(as lme4::glmer, nAGQ = {n_quad})")
    out.attrs.update(
        method=method,
        formula=f"{outcome} ~ {rhs} + " + " + ".join(f"(1 | {c})" for c in re_cols),
        deviance=f0, n_trials=int(len(d)), n_participants=int(d[subject].nunique()),
        reference_levels={f: lv[0] for f, lv in levels.items()},
        converged=not [p for p in problems if "did not converge" in p
                       or "not positive definite" in p],
        problems=problems, gradient=g.tolist())
    if problems:
        msg = f"mixed logistic model {out.attrs['formula']}: " + "; ".join(problems)
        if on_failure == "error":
            raise InputError(msg)
        warnings.warn(MixedModelWarning(msg), stacklevel=2)
    return out
