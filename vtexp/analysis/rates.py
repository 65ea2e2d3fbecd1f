"""Recognition rates: share of correct answers per condition and participant."""

from __future__ import annotations

import numpy as np
import pandas as pd


def recognition_rates(trials: pd.DataFrame, by: list[str], *,
                      per_participant: bool = False) -> pd.DataFrame:
    """Rate of correct answers grouped by ``by`` (and by participant if asked).

    Trials without a scored answer (``correct`` missing) are left out. With
    ``per_participant=False`` the rate of a condition is the mean of the
    participants' rates (each participant weighs the same, as in the papers'
    figures), with its standard error across participants; ``n_trials`` and
    ``n_correct`` are the pooled counts.
    """
    scored = trials[trials["correct"].notna()].copy()
    scored["correct"] = scored["correct"].astype(float)
    keys = ["experiment", "participant", *by]
    per = (scored.groupby(keys, sort=True, observed=True)["correct"]
           .agg(n_trials="size", n_correct="sum", rate="mean").reset_index())
    per["n_correct"] = per["n_correct"].astype(int)
    if per_participant:
        return per
    g = per.groupby(["experiment", *by], sort=True, observed=True)
    out = g.agg(n_participants=("participant", "nunique"), n_trials=("n_trials", "sum"),
                n_correct=("n_correct", "sum"), rate=("rate", "mean"),
                sd=("rate", "std")).reset_index()
    out["se"] = out["sd"] / np.sqrt(out["n_participants"])
    return out.drop(columns="sd")
