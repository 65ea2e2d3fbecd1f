"""Psychometric fits of adaptive sessions: one per participant (and per level of ``by``).

Reads only the trial table: the level played (``presented``) and whether the answer
counts as a yes (the ``adaptive.response`` of the experiment as the session recorded
it: the listed answers, or a correct answer). Fits by maximum likelihood with a
parametric-bootstrap interval (:func:`vtexp.adaptive.fit.fit_psychometric`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..adaptive.fit import fit_psychometric
from ..errors import InputError


def answers_as_yes(trials: pd.DataFrame, adaptive: dict) -> pd.DataFrame:
    """The rows of the procedure's question that were played, with ``level`` and ``yes``."""
    if "presented" not in trials.columns:
        raise InputError("these sessions have no 'presented' column: the psychometric fit "
                         "needs an experiment with an 'adaptive:' section")
    response = adaptive.get("response") or {}
    question = response.get("question")
    d = trials
    if question is not None:
        d = d[d["question"] == question]
    elif "question" in d.columns and d["question"].nunique() > 1:
        d = d[d["question"] == d["question"].iloc[0]]
    d = d[(d["status"] == "ok") & d["answer"].notna()].copy()
    d["level"] = pd.to_numeric(d["presented"], errors="coerce")
    d = d[d["level"].notna()]
    yes = response.get("yes_answers")
    d["yes"] = d["answer"].isin(yes) if yes else d["correct"].astype(float) == 1.0
    return d


def psychometric_fits(trials: pd.DataFrame, adaptive: dict, *, function: str | None = None,
                      guess: float | None = None, lapse: float | str = "free",
                      max_lapse: float = 0.1, bootstrap: int = 200, by: list[str] | None = None
                      ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(fits, points)``: a row per participant (and ``by`` level) with the threshold,
    its interval, slope, lapse, log-likelihood; and the proportion of yes per level."""
    proc = adaptive.get("procedure") or {}
    function = function or proc.get("function", "weibull")
    guess = proc.get("guess", 0.0) if guess is None else guess
    by = list(by or [])
    d = answers_as_yes(trials, adaptive)
    keys = ["participant", *by]
    fits, points = [], []
    for key, g in d.groupby(keys, observed=True, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        name = "/".join(str(k) for k in key)
        f = fit_psychometric(g["level"].to_numpy(float), g["yes"].to_numpy(bool),
                             function=function, guess=guess, lapse=lapse, max_lapse=max_lapse,
                             bootstrap=bootstrap, name=name)
        row = dict(zip(keys, (str(k) for k in key), strict=True))
        fits.append({**row, "function": function, "n_trials": f.n_trials,
                     "threshold": f.threshold, "threshold_ci_low": f.threshold_ci[0],
                     "threshold_ci_high": f.threshold_ci[1], "slope": f.slope,
                     "slope_ci_low": f.slope_ci[0], "slope_ci_high": f.slope_ci[1],
                     "guess": f.guess, "lapse": f.lapse, "loglik": f.loglik,
                     "n_bootstrap": f.n_bootstrap, "converged": f.converged})
        p = g.groupby("level")["yes"].agg(["sum", "count"]).reset_index()
        for r in p.itertuples():
            points.append({**row, "level": float(r.level), "n": int(r.count),
                           "yes": int(r.sum), "proportion": r.sum / r.count})
    return pd.DataFrame(fits), pd.DataFrame(points)


def fit_sentence(row: pd.Series, variable: str, by: list[str]) -> str:
    where = "".join(f", {b} = {row[b]}" for b in by)
    return (f"Participant {row['participant']}{where}: threshold of {variable} "
            f"{row['threshold']:.1f} (95 % CI {row['threshold_ci_low']:.1f}–"
            f"{row['threshold_ci_high']:.1f}, parametric bootstrap, {row['n_bootstrap']} "
            f"samples), slope {row['slope']:.2f}, lapse {row['lapse']:.3f}; {row['function']} "
            f"fitted by maximum likelihood to {row['n_trials']} trials.")


def curve(row: pd.Series, levels: np.ndarray) -> np.ndarray:
    from ..adaptive.psychometric import psi

    return psi(levels, row["threshold"], row["slope"], row["guess"], row["lapse"],
               row["function"])
