"""A stated design: each participant's measure per condition, drawn from stated means, SDs and r.

``vtexp simulate EXP --observer FILE`` with a file of ``kind: stated`` does not run the
model participant: each simulated participant's measure in each of the experiment's
conditions (a rate, a rating, whatever its declared ANOVAs read) is one draw from a
multivariate normal with the stated means, SDs and correlations, and goes straight into
the same declared tests, intervals and N search. Its power is known exactly
(:mod:`vtexp.analysis.exact_power`), so such a file checks ``vtexp simulate``'s power
machinery. The file::

    kind: stated
    description: what the numbers are (optional)
    question: shape_rating     # optional: which question's measure; needed when the
                               # experiment's ANOVAs read different questions
    means:                     # one mean per condition, nested by the experiment's
      circle:                  # factors in their order (shape, then corners)
        plain: 0.8
        emphasised: 1.0
      rectangle: {plain: -0.4, emphasised: -1.0}
    sd: 1.0                    # one SD, or one per condition nested like means
    r: 0.5                     # one correlation for every pair of conditions, or a
                               # matrix whose rows and columns are the conditions in
                               # the order they are written under means

Participant ``i`` of study ``s`` under seed ``S`` draws ``x = μ + L z`` (``Σ = L Lᵀ``,
``Σ = D R D``), ``z`` the normals of the uniform stream keyed ("stated", S, s): row
``i``, so the draws are the same on every machine and whichever worker runs the study.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..yamlio import LoadedYaml, load_yaml
from .params import normals, uniform_stream

KEYS = ("kind", "description", "question", "means", "sd", "r")


def stated_kind(path: Path | str) -> bool:
    """Whether an observer file states a design (``kind: stated``) rather than the model
    participant's parameters (no ``kind``). Any other kind is refused."""
    if not Path(path).is_file():
        return False                  # the parameters' loader says so, as it always has
    doc = load_yaml(path)
    if not isinstance(doc.data, dict) or "kind" not in doc.data:
        return False
    if doc.data["kind"] != "stated":
        raise InputError(f"{doc.data['kind']!r} is not a kind of observer file: 'stated' "
                         "(means, sd, r of each condition), or leave kind out for the model "
                         "participant's parameters", path=str(path),
                         line=doc.line_of(("kind",)), key="kind")
    return True


@dataclass(frozen=True)
class StatedMeasures:
    """Means and covariance of a participant's measure in each condition (experiment order)."""

    path: str
    conditions: list[dict[str, str]]     # each condition's factor levels
    means: np.ndarray                    # (conditions,)
    cov: np.ndarray                      # (conditions, conditions)
    question: str | None
    description: str = ""

    @property
    def chol(self) -> np.ndarray:
        return np.linalg.cholesky(self.cov)

    def draw(self, seed: int, study: int, n: int) -> np.ndarray:
        """The measures of study ``study``'s ``n`` participants: (n, conditions)."""
        z = normals(uniform_stream("stated", seed, study), (n, self.means.size))
        return self.means + z @ self.chol.T


def _number(doc: LoadedYaml, keypath: tuple, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise InputError(f"expected a number, got {value!r}", path=doc.path,
                         line=doc.line_of(keypath), key=".".join(map(str, keypath)))
    return float(value)


def _per_condition(doc: LoadedYaml, key: str, factors: dict[str, list[str]],
                   conditions: list[tuple]) -> dict[tuple, tuple[float, tuple]]:
    """A mapping nested by the factors, read into {condition: (value, its key path)}."""
    names = list(factors)
    known = set(conditions)
    out: dict[tuple, tuple[float, tuple]] = {}

    def walk(node: Any, depth: int, levels: tuple, keypath: tuple) -> None:
        if depth == len(names):
            out[levels] = (_number(doc, keypath, node), keypath)
            return
        f = names[depth]
        if not isinstance(node, dict):
            raise InputError(f"expected a mapping of the levels of {f} "
                             f"({', '.join(factors[f])}) to "
                             f"{'numbers' if depth == len(names) - 1 else 'mappings'}",
                             path=doc.path, line=doc.line_of(keypath),
                             key=".".join(map(str, keypath)))
        for level, sub in node.items():
            kp = keypath + (level,)
            if str(level) not in factors[f]:
                raise InputError(f"{level!r} is not a level of {f} ({', '.join(factors[f])})",
                                 path=doc.path, line=doc.line_of(kp),
                                 key=".".join(map(str, kp)))
            lv = levels + (str(level),)
            if not any(c[:len(lv)] == lv for c in known):
                raise InputError("no condition of the experiment has "
                                 + ", ".join(f"{n} = {v}" for n, v in zip(names, lv)),
                                 path=doc.path, line=doc.line_of(kp),
                                 key=".".join(map(str, kp)))
            walk(sub, depth + 1, lv, kp)

    walk(doc.data[key], 0, (), (key,))
    for c in conditions:
        if c not in out:
            raise InputError("no value for the condition "
                             + ", ".join(f"{n} = {v}" for n, v in zip(names, c))
                             + " (every condition of the experiment needs one)",
                             path=doc.path, line=doc.line_of((key,)), key=key)
    return out


def load_stated(path: Path | str, lx) -> StatedMeasures:
    """Read and check a stated file against the experiment ``lx`` (a LoadedExperiment)."""
    from ..compile import enumerate_conditions

    doc = load_yaml(path)
    p = str(path)
    data = doc.data
    if not isinstance(data, dict):
        raise InputError("expected a mapping (kind: stated, means:, sd:, r:)", path=p, line=1)
    for k in data:
        if k not in KEYS:
            raise InputError(f"unknown key (a stated file has {', '.join(KEYS)})", path=p,
                             line=doc.line_of((k,)), key=str(k))
    for k in ("means", "sd", "r"):
        if k not in data:
            raise InputError(f"missing: a stated file gives {k}", path=p, line=1, key=k)
    exp = lx.experiment
    factors = {n: list(f.level_names) for n, f in exp.factors.items()}
    conds = enumerate_conditions(lx)
    combos = [tuple(c.levels[n] for n in factors) for c in conds]

    question = data.get("question")
    asked = [q.name for q in exp.asked()]
    if question is not None and question not in asked:
        raise InputError(f"the experiment asks no question {question!r} (it asks "
                         f"{', '.join(asked)})", path=p, line=doc.line_of(("question",)),
                         key="question")
    spec = exp.analysis
    read = sorted({str(a.where["question"]) for a in (spec.anova if spec else [])
                   if "question" in a.where})
    if question is None and len(read) > 1:
        raise InputError(f"the experiment's ANOVAs read different questions "
                         f"({', '.join(read)}); say which one the means are of",
                         path=p, line=1, key="question")

    means = _per_condition(doc, "means", factors, combos)
    written = list(means)                   # the order they are written in
    mu = np.array([means[c][0] for c in combos])

    if isinstance(data["sd"], dict):
        sds = _per_condition(doc, "sd", factors, combos)
        sd = np.array([sds[c][0] for c in combos])
        where = {c: sds[c][1] for c in combos}
    else:
        sd = np.full(len(combos), _number(doc, ("sd",), data["sd"]))
        where = {c: ("sd",) for c in combos}
    for c, s in zip(combos, sd):
        if not s > 0:
            raise InputError(f"an SD must be above 0, not {s:g}", path=p,
                             line=doc.line_of(where[c]), key=".".join(map(str, where[c])))

    k = len(combos)
    r = data["r"]
    if isinstance(r, list):
        if len(r) != k or not all(isinstance(row, list) and len(row) == k for row in r):
            raise InputError(f"a correlation matrix has a row and a column per condition: "
                             f"{k} × {k}, in the order of the conditions under means",
                             path=p, line=doc.line_of(("r",)), key="r")
        W = np.array([[_number(doc, ("r", i, j), v) for j, v in enumerate(row)]
                      for i, row in enumerate(r)])
        order = [written.index(c) for c in combos]       # written order -> experiment order
        R = W[np.ix_(order, order)]
        if not np.allclose(np.diag(R), 1.0):
            raise InputError("the diagonal of a correlation matrix is 1", path=p,
                             line=doc.line_of(("r",)), key="r")
        if not np.allclose(R, R.T, rtol=0, atol=1e-12):
            raise InputError("the correlation matrix is not symmetric", path=p,
                             line=doc.line_of(("r",)), key="r")
    else:
        R = np.full((k, k), _number(doc, ("r",), r))
        np.fill_diagonal(R, 1.0)
    if (np.abs(R) > 1).any():
        raise InputError("a correlation is between -1 and 1", path=p,
                         line=doc.line_of(("r",)), key="r")
    cov = sd[:, None] * R * sd[None, :]
    if not np.linalg.eigvalsh(cov).min() > 1e-12 * float(np.trace(cov)):
        low = f" (one r for {k} conditions must be above {-1 / (k - 1):.3g})" \
            if not isinstance(r, list) and k > 1 else ""
        raise InputError("the correlations are not positive definite: no participants can "
                         f"have them{low}", path=p, line=doc.line_of(("r",)), key="r")
    desc = data.get("description") or ""
    return StatedMeasures(p, [dict(zip(factors, c)) for c in combos], mu, cov, question,
                          str(desc))
