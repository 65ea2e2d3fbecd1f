"""Psychometric fits of adaptive sessions: one per participant (and per level of ``by``).

Reads only the trial table: the level played (``presented``) and whether the answer
counts as a yes (the ``adaptive.response`` of the experiment as the session recorded
it: the listed answers, or a correct answer). Fits by maximum likelihood with a
parametric-bootstrap interval (:func:`vtexp.adaptive.fit.fit_psychometric`).

:func:`procedure_estimates` gives, next to the fit, the procedure's own estimate per
participant, session and track: the answers of each track, in trial order, are fed
again to the procedure the session ran (:func:`vtexp.adaptive.track.replay_estimate`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..adaptive.fit import fit_psychometric
from ..adaptive.psychometric import psi
from ..adaptive.spec import AdaptiveSpec, procedure_spec, value_list
from ..adaptive.track import replay_estimate
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
                     "n_levels": int(g["level"].nunique()),
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


def _yes(d: pd.DataFrame, response: dict) -> pd.Series:
    yes = response.get("yes_answers")
    return d["answer"].isin(yes) if yes else pd.to_numeric(d["correct"], errors="coerce") == 1.0


def procedure_estimates(trials: pd.DataFrame, adaptive: dict, factors: dict
                        ) -> pd.DataFrame:
    """A row per participant, session and track: the procedure's estimate of the threshold
    (a staircase's mean of its last reversals, QUEST's and QUEST+'s posterior mean) with
    its SD, and QUEST+'s slope and lapse, recomputed by replaying the log.

    ``adaptive`` and ``factors`` are the experiment's sections as the session recorded
    them (``experiment_loaded``). Every answered trial of the procedure's question
    (``status`` ok, practice excluded) counts, as it did in the session.
    """
    spec = AdaptiveSpec.model_validate(adaptive)
    response = adaptive.get("response") or {}
    d = trials
    question = response.get("question")
    if question is None and "question" in d.columns:
        question = d["question"].iloc[0] if len(d) else None
    if question is not None:
        d = d[d["question"] == question]
    if "practice" in d.columns:
        d = d[pd.to_numeric(d["practice"], errors="coerce").fillna(0) == 0]
    d = d[d["status"] == "ok"].copy()
    d["level"] = pd.to_numeric(d["presented"], errors="coerce")
    d = d[d["level"].notna()]
    d["yes"] = _yes(d, response)
    track_factors = spec.tracks if spec.tracks is not None else list(factors)
    values = value_list(spec.values)
    rows = []
    keys = ["participant", "session"]
    for key, g in d.groupby(keys + track_factors, observed=True, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        levels = dict(zip(track_factors, (str(k) for k in key[2:]), strict=True))
        overrides: dict = {}
        for f, lv in levels.items():
            fs = factors.get(f) or {}
            if fs.get("sets") == "adaptive" and isinstance(fs.get("levels"), dict):
                overrides.update(fs["levels"].get(lv) or {})
        g = g.sort_values("trial")
        est = replay_estimate(procedure_spec(spec, overrides), values,
                              g["level"].to_list(), g["yes"].to_list())
        rows.append({"participant": str(key[0]), "session": int(key[1]),
                     "track": ", ".join(f"{f}={v}" for f, v in levels.items()), **est})
    return pd.DataFrame(rows)


def estimate_sentence(row: pd.Series, variable: str, *, track: bool, session: bool) -> str:
    where = (f", session {row['session']}" if session else "") + \
        (f", track {row['track']}" if track else "")
    head = f"Participant {row['participant']}{where}: "

    def sd(k: str) -> str:
        v = row[f"{k}_sd"]
        return f" (SD {v:.2f})" if pd.notna(v) else ""
    if row["procedure"] == "staircase":
        if pd.isna(row["threshold"]):
            return head + f"the staircase made no reversal in {row['n_trials']} trials, so it "\
                "gives no estimate."
        return (head + f"the staircase's estimate of {variable}, the mean of its last "
                f"{row['reversals_used']} of {row['n_reversals']} reversals, "
                f"{row['threshold']:.2f}{sd('threshold')}; {row['n_trials']} trials.")
    name = "QUEST" if row["procedure"] == "quest" else "QUEST+"
    text = (head + f"{name}'s posterior mean of the threshold of {variable} "
            f"{row['threshold']:.2f}{sd('threshold')}")
    if row["procedure"] == "questplus":
        text += (f", slope {row['slope']:.2f}{sd('slope')}, lapse {row['lapse']:.3f}"
                 + (f" (SD {row['lapse_sd']:.3f})" if pd.notna(row['lapse_sd']) else ""))
    return text + f"; {row['n_trials']} trials."


def fit_sentence(row: pd.Series, variable: str, by: list[str]) -> str:
    where = "".join(f", {b} = {row[b]}" for b in by)
    return (f"Participant {row['participant']}{where}: threshold of {variable} "
            f"{row['threshold']:.1f} (95 % CI {row['threshold_ci_low']:.1f}–"
            f"{row['threshold_ci_high']:.1f}, parametric bootstrap, {row['n_bootstrap']} "
            f"samples), slope {row['slope']:.2f}, lapse {row['lapse']:.3f}; {row['function']} "
            f"fitted by maximum likelihood to {row['n_trials']} trials"
            + (f" at only {row['n_levels']} level{'s' if row['n_levels'] != 1 else ''}: the "
               "slope and the interval may be poorly determined; compare the procedure's "
               "estimate"
               if "n_levels" in row and row["n_levels"] < 3 else "") + ".")


def curve(row: pd.Series, levels: np.ndarray) -> np.ndarray:
    return psi(levels, row["threshold"], row["slope"], row["guess"], row["lapse"],
               row["function"])
