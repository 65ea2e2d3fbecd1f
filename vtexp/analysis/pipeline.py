"""Run an experiment's declared analyses on its trial table.

:func:`analyse_experiment` computes every table the report shows, each with a
function of this package that takes a tidy table and returns a tidy table; the
report (:mod:`.report`) only formats the :class:`ExperimentAnalysis` it gets.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from .anova import MissingCellsWarning, rm_anova, simple_effects
from .confusion import agreement, confusion_matrix, information_transfer
from .effect_sizes import ETA2P_CI_LEVEL, eta2p_ci
from .glmm import MixedModelWarning, mixed_logit
from .load import SessionData
from .ordinal import friedman, wilcoxon_pairwise
from .participants import join_participants, read_participants
from .posthoc import pairwise_tests
from .psychometric import (estimate_sentence, fit_sentence, procedure_estimates,
                           psychometric_fits)
from .rates import recognition_rates
from .spec import AnalysisSpec, PsychometricSpec, default_spec

__all__ = ["ExperimentAnalysis", "analyse_experiment", "participant_measures", "spec_for",
           "apa_anova", "eta2p_interval", "format_p"]

MEASURE_LABEL = {"rate": "recognition rate", "rt_s": "reaction time (s)",
                 "replays": "replays", "answer": "rating"}


def questions_of(loaded: dict) -> list[dict]:
    """The questions of an experiment as recorded in its sessions (``question(s):``)."""
    if loaded.get("questions"):
        return [q for q in loaded["questions"] if q]
    return [loaded["question"]] if loaded.get("question") else []


def _question_for(where: dict, questions: list[dict]) -> dict | None:
    """The question whose answers an analysis with ``where`` reads, if it is one."""
    named = where.get("question")
    if isinstance(named, str):
        return next((q for q in questions if q.get("name") == named), {"name": named})
    return questions[0] if len(questions) == 1 else None


def measure_label(dv: str, where: dict, questions: list[dict]) -> str:
    """What the measure is, in words, for sentences, captions and axes.

    ``answer`` is named after its question: a rating question's name with
    'rating' ('sensation rating'), a number question's as a count ('number of
    turns'); the other measures by :data:`MEASURE_LABEL`.
    """
    if dv != "answer":
        return MEASURE_LABEL[dv]
    q = _question_for(where, questions) or {}
    name = str(q.get("name") or "").replace("_", " ").strip()
    if q.get("kind") == "number":
        if not name or "count" in name or "number" in name:
            return name or "count"
        return f"number of {name}"
    if name in ("", "rating", "response"):
        return "rating"
    return name if "rating" in name else f"{name} rating"


def rating_scale(dv: str, where: dict, questions: list[dict]) -> dict[int, str] | None:
    """The points of the rating scale an ``answer`` measure is on, with their words."""
    if dv != "answer":
        return None
    q = _question_for(where, questions) or {}
    if q.get("kind") != "rating" or "low" not in q or "high" not in q:
        return None
    words = {int(k): str(v) for k, v in (q.get("labels") or {}).items()}
    return {v: words.get(v, "") for v in range(int(q["low"]), int(q["high"]) + 1)}


@dataclass
class FigureData:
    """One declared figure: the table it draws (``key`` in the tables) and its words."""

    key: str
    x: str
    trace: str | None
    dv: str
    label: str
    where_text: str = ""
    scale: dict[int, str] | None = None


@dataclass
class ExperimentAnalysis:
    experiment: str
    title: str
    reference: str
    factors: list[str]
    levels: dict[str, list[str]]
    spec: AnalysisSpec
    spec_source: str
    sessions: pd.DataFrame
    n_participants: int
    n_trials: int
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    #: headings of tables that name their measure (key -> heading); others by kind
    titles: dict[str, str] = field(default_factory=dict)
    figures: list[FigureData] = field(default_factory=list)
    sentences: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------- measures

def participant_measures(trials: pd.DataFrame, dv: str, by: list[str]) -> pd.DataFrame:
    """One value of the measure per participant and cell of ``by`` (mean over trials).

    ``rate``: share of correct answers among scored trials; ``rt_s``, ``replays``:
    mean over answered trials; ``answer``: the answer read as a number (ratings).
    """
    keys = ["participant", *by]
    if dv == "rate":
        t = trials[trials["correct"].notna()].assign(value=lambda d: d["correct"].astype(float))
    elif dv == "answer":
        t = trials.assign(value=pd.to_numeric(trials["answer"], errors="coerce"))
        if t["value"].isna().all():
            raise InputError("the answers are not numbers, so 'dv: answer' cannot be analysed "
                             "(use it for rating scales)")
        t = t[t["value"].notna()]
    else:
        t = trials.assign(value=pd.to_numeric(trials[dv], errors="coerce"))
        t = t[t["value"].notna()]
    out = (t.groupby(keys, observed=True, sort=True)["value"]
           .agg(value="mean", n_trials="size").reset_index())
    return out.rename(columns={"value": dv})


# --------------------------------------------------------------------------- formatting helpers

def format_p(p: float) -> str:
    """APA: 'p < .001', else 'p = .034' (three decimals, no leading zero)."""
    if p is None or np.isnan(p):
        return "p = n/a"
    if p < 0.001:
        return "p < .001"
    return "p = " + f"{p:.3f}".lstrip("0")


def _fixed(x: float, digits: int = 2) -> str:
    """Round half up on the shortest decimal form (28.775 -> 28.78), as people round."""
    if x != x or x in (float("inf"), float("-inf")):
        return "n/a"
    return str(Decimal(repr(float(x))).quantize(Decimal(1).scaleb(-digits), ROUND_HALF_UP))


def _num2(x: float) -> str:
    """Two decimals without the leading zero, for values bounded by 1 (η², ε)."""
    s = _fixed(x, 2)
    return s.replace("0.", ".", 1) if s.startswith("0.") else s.replace("-0.", "-.", 1)


def _df(x: float) -> str:
    if not np.isfinite(x):
        return "n/a"
    return f"{x:.0f}" if abs(x - round(x)) < 1e-9 else _fixed(x, 2)


def _bound(x: float) -> str:
    """An η² limit: '0' and '1' exactly, else two decimals without the leading zero."""
    return "0" if x == 0 else ("1" if x == 1 else _num2(x))


def eta2p_interval(F: float, df1: float, df2: float) -> str:
    """'90% CI [.39, .81]' for partial η² from F on (df1, df2), or the reason there is none."""
    lo, hi = eta2p_ci(F, df1, df2, ETA2P_CI_LEVEL)
    level = f"{ETA2P_CI_LEVEL * 100:.0f}% CI"
    if lo != lo:
        why = "no error variance" if F == float("inf") else "F is not defined"
        return f"{level} n/a ({why})"
    return f"{level} [{_bound(lo)}, {_bound(hi)}]"


def apa_anova(row: pd.Series, correction: str = "auto") -> tuple[str, str]:
    """APA sentence for one ANOVA row, and the correction used.

    'F(1, 14) = 28.78, p < .001, η²p = .67, 90% CI [.39, .81]'; with a
    sphericity correction the dfs are multiplied by ε and the correction is
    named: 'F(1.37, 15.08) = 3.00, p = .094, η²p = .21, 90% CI [0, .47],
    ε = .46 (Greenhouse–Geisser)' (a limit of exactly 0 is printed '0').
    ``auto`` applies Greenhouse–Geisser when Mauchly's p < .05, or when the
    test is undefined (fewer participants than the effect's df + 1).

    The interval of η²p is the one that goes with the test printed: from the
    noncentral F on the df shown (corrected or not), so it excludes 0 exactly
    when p < .05 (:func:`.effect_sizes.eta2p_ci`). An F that is not finite
    gets no sentence of numbers but the reason ("F not applicable: ...").
    """
    if not np.isfinite(row["F"]):
        why = ("the measure does not vary across these cells (effect and error sums of "
               "squares are 0)" if row["F"] != row["F"] else
               "the error sum of squares is 0 (every participant shows the same effect)")
        return f"F not applicable: {why}", "none"
    used = correction
    if correction == "auto":
        used = "GG" if (row["df1"] > 1 and not row["mauchly_p"] >= 0.05) else "none"
    if used == "none" or row["df1"] == 1:
        df1, df2, p, eps = row["df1"], row["df2"], row["p"], None
        used = "none"
    elif used == "GG":
        eps = row["eps_gg"]
        df1, df2, p = row["df1"] * eps, row["df2"] * eps, row["p_gg"]
    else:
        eps = min(row["eps_hf"], 1.0)
        df1, df2, p = row["df1"] * eps, row["df2"] * eps, row["p_hf"]
    s = (f"F({_df(df1)}, {_df(df2)}) = {_fixed(row['F'])}, {format_p(p)}, "
         f"η²p = {_num2(row['pes'])}, {eta2p_interval(row['F'], df1, df2)}")
    if eps is not None:
        s += f", ε = {_num2(eps)} ({'Greenhouse–Geisser' if used == 'GG' else 'Huynh–Feldt'})"
    return s, used


# --------------------------------------------------------------------------- the analysis

def spec_for(sessions: list[SessionData], experiment: str, override: AnalysisSpec | None,
             factors: list[str], scored: bool) -> tuple[AnalysisSpec, str, list[str]]:
    """The analysis to run: the override, else the sessions' recorded one, else the default."""
    notes: list[str] = []
    if override is not None:
        return override, "the experiment file given with --experiment", notes
    recorded = [s.meta.get("experiment_loaded", {}).get("analysis") for s in sessions
                if s.meta.get("experiment") == experiment]
    declared = [r for r in recorded if r]
    if declared:
        distinct = {repr(sorted(d.items())) for d in declared}
        if len(distinct) > 1:
            notes.append("the sessions record different 'analysis:' sections; the last "
                         "session's is used")
        try:
            spec = AnalysisSpec.model_validate(declared[-1])
        except Exception as e:          # pydantic error from an older or edited record
            raise InputError(f"the 'analysis:' section recorded in the sessions of {experiment} "
                             f"is not valid: {e}") from None
        return spec, "the 'analysis:' section recorded in the sessions", notes
    stim = next((n for s in sessions if s.meta.get("experiment") == experiment
                 for n, f in s.meta.get("experiment_loaded", {}).get("factors", {}).items()
                 if f.get("sets") == "stimulus"), None)
    return (default_spec(factors, stim, scored),
            "the default analysis (the experiment declares no 'analysis:' section)", notes)


def _session_table(sessions: list[SessionData]) -> pd.DataFrame:
    rows = []
    for s in sessions:
        # a trial with two questions is two rows of the log; count trials, not rows
        n_trials = int(s.trials["trial"].nunique()) if "trial" in s.trials.columns \
            else len(s.trials)
        rows.append({"participant": str(s.meta.get("participant")),
                     "session": s.meta.get("session"), "status": s.status,
                     "trials": n_trials,
                     "planned": s.meta.get("n_trials_planned"),
                     "checksum": s.checksum, "folder": str(s.dir)})
    return pd.DataFrame(rows)


def _subset(trials: pd.DataFrame, where: dict) -> pd.DataFrame:
    """The trials at the levels ``where`` names; levels left unused are dropped."""
    if not where:
        return trials
    keep = np.ones(len(trials), bool)
    for factor, levels in where.items():
        wanted = [levels] if isinstance(levels, str) else list(levels)
        keep &= trials[factor].astype(str).isin(wanted).to_numpy()
    out = trials[keep].copy()
    for col in out.columns:
        if isinstance(out[col].dtype, pd.CategoricalDtype):
            out[col] = out[col].cat.remove_unused_categories()
    return out


def _capital(text: str) -> str:
    return text[:1].upper() + text[1:]


def _where_text(where: dict) -> str:
    if not where:
        return ""
    parts = [f"{f} = {v if isinstance(v, str) else ' or '.join(v)}" for f, v in where.items()]
    return " (" + ", ".join(parts) + ")"


def participants_table(sessions: list[SessionData]):
    """The participants table (BIDS ``participants.tsv``) of the sessions' dataset, or None.

    The one vtexp writes at the root of the sessions' dataset; for data folders of
    the layout before BIDS, one a lab put in the folder of the sessions or above it.
    """
    seen = set()
    for s in sessions:
        roots = [s.root] if getattr(s, "root", None) is not None else []
        for folder in roots + list(Path(s.dir).parents)[1:4]:
            f = folder / "participants.tsv"
            if f in seen:
                continue
            seen.add(f)
            if f.is_file():
                return read_participants(f), f
    return None, None


def _with_groups(trials: pd.DataFrame, sessions: list[SessionData], names: list[str]):
    """``trials`` with the between factors ``names`` taken from the participants table."""
    lacking = [n for n in names if n not in trials.columns]
    if not lacking:
        return trials
    table, path = participants_table(sessions)
    if table is None:
        raise InputError(f"the analysis names between-participant factor(s) "
                         f"{', '.join(lacking)}, which come from the participants table "
                         "(participants.tsv in the data folder), and there is none")
    missing = [n for n in lacking if n not in table.columns]
    if missing:
        raise InputError(f"{path}: no column {', '.join(map(repr, missing))} (its columns: "
                         f"{', '.join(table.columns)})")
    joined = join_participants(trials, table[["participant_id", *lacking]], "participant")
    for n in lacking:
        unknown = sorted(joined.loc[joined[n].isna(), "participant"].astype(str).unique())
        if unknown:
            raise InputError(f"{path}: {n} is n/a for participant(s) "
                             f"{', '.join('sub-' + u for u in unknown[:8])}; the analysis "
                             f"needs it (give it at the first session: vtexp run "
                             f"--participant-info {n}=..., or fill it in participants.tsv)")
    return joined


def analyse_experiment(trials: pd.DataFrame, sessions: list[SessionData], experiment: str, *,
                       spec: AnalysisSpec | None = None) -> ExperimentAnalysis:
    """Every table of one experiment's report, from its tidy trial table.

    ``trials`` is the table of :func:`load_sessions` (practice excluded);
    ``spec`` overrides the ``analysis:`` section recorded in the sessions.
    """
    sub = trials[trials["experiment"] == experiment]
    mine = [s for s in sessions if s.meta.get("experiment") == experiment]
    if sub.empty or not mine:
        raise InputError(f"no trials of experiment {experiment!r}")
    override = spec
    loaded = mine[-1].meta.get("experiment_loaded", {})
    factors = mine[0].factors
    levels = mine[0].levels
    scored = bool(sub["correct"].notna().any())
    spec, source, notes = spec_for(sessions, experiment, override, factors, scored)
    problems = spec.unknown_factors(factors)
    if problems:
        raise InputError(problems[0] + f" ({source})")
    if spec.between_factors():
        sub = _with_groups(sub, mine, spec.between_factors())
    res = ExperimentAnalysis(
        experiment=experiment, title=loaded.get("title", experiment),
        reference=loaded.get("reference", ""), factors=factors, levels=levels, spec=spec,
        spec_source=source, sessions=_session_table(mine),
        n_participants=int(sub["participant"].nunique()), n_trials=len(sub), notes=notes)
    T = res.tables
    caught: list[warnings.WarningMessage] = []

    def run(fn, *a, **kw):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always", MissingCellsWarning)
            out = fn(*a, **kw)
        caught.extend(w)
        return out

    def attempt(what: str, fn, *a, **kw):
        """``run``, or None with a note saying why the test was skipped when the data
        cannot carry it (a pilot: too few participants with every cell, a level no one
        reached); the tables and figures of the report are written all the same."""
        try:
            return run(fn, *a, **kw)
        except InputError as e:
            note = f"{what}: skipped ({e.message})"
            if note not in notes:
                notes.append(note)
            return None

    if scored:
        T["rates_by_condition"] = recognition_rates(sub, factors).drop(columns="experiment")
        for f in factors:
            T[f"rates_by_{f}"] = recognition_rates(sub, [f]).drop(columns="experiment")
        T["rates_by_participant"] = recognition_rates(sub, [], per_participant=True) \
            .drop(columns="experiment")
    if spec.table:
        T["recognition_table"] = recognition_table(sub, spec.table.rows, spec.table.columns,
                                                   pooled=spec.table.pooled)
    questions = questions_of(loaded)

    def label(dv: str, where: dict) -> str:
        return measure_label(dv, where, questions)

    def rows(dv: str, where: dict) -> str:
        """The rows an analysis reads, in words; a question its measure is named after
        is not said twice ('Number of turns', not 'Number of turns (question = turns)')."""
        named = dv == "answer" and isinstance(where.get("question"), str)
        return _where_text({k: v for k, v in where.items() if not (named and k == "question")})

    for i, fs in enumerate(spec.figures()):
        by = [fs.x] + ([fs.trace] if fs.trace else [])
        key = "figure_per_participant" + (f"_{i + 1}" if i else "")
        T[key] = participant_measures(_subset(sub, fs.where), fs.dv, by)
        res.figures.append(FigureData(key=key, x=fs.x, trace=fs.trace, dv=fs.dv,
                                      label=label(fs.dv, fs.where),
                                      where_text=rows(fs.dv, fs.where),
                                      scale=rating_scale(fs.dv, fs.where, questions)))

    if res.n_participants < 2 and (spec.anova or spec.simple_effects or spec.posthoc
                                   or spec.ordinal):
        notes.append(f"{res.n_participants} participant: the repeated-measures tests need at "
                     "least 2 and were skipped")
    else:
        for i, a in enumerate(spec.anova):
            within = a.within or factors
            m = participant_measures(_subset(sub, a.where), a.dv, within + a.between)
            t = attempt(f"The ANOVA of the {label(a.dv, a.where)}", rm_anova, m, a.dv, within,
                        "participant", between=a.between, observed=a.observed or None)
            if t is None:
                continue
            T[f"anova_{i + 1}"] = t
            res.titles[f"anova_{i + 1}"] = (
                f"{'Mixed' if a.between else 'Repeated-measures'} ANOVA of the "
                f"{label(a.dv, a.where)}{rows(a.dv, a.where)}")
            for _, row in t.iterrows():
                sentence, used = apa_anova(row, a.correction)
                row_note = ""
                if used != "none":
                    row_note = (f" (Mauchly's W = {row['mauchly_W']:.2f}, "
                                f"{format_p(row['mauchly_p'])})"
                                if row["mauchly_p"] == row["mauchly_p"] else
                                " (Mauchly's test undefined: fewer participants than df + 1)")
                res.sentences.append(
                    f"{_capital(label(a.dv, a.where))}, {' × '.join(a.between + within)}"
                    f"{rows(a.dv, a.where)}: effect of "
                    f"{row['effect'].replace(':', ' × ')}: {sentence}{row_note}.")
            if a.note:
                res.sentences.append(f"(The paper: {a.note}.)")
        for i, s in enumerate(spec.simple_effects):
            within = s.within or factors
            m = participant_measures(_subset(sub, s.where), s.dv, within + s.between)
            methods = ["separate", "pooled"] if s.method == "both" else [s.method]
            parts = [attempt(f"The simple effects of {s.effect} at each {s.by}", simple_effects,
                             m, s.dv, within, "participant", effect=s.effect, by=s.by,
                             method=meth, between=s.between) for meth in methods]
            if any(part is None for part in parts):
                continue
            t = pd.concat(parts, ignore_index=True)
            T[f"simple_effects_{i + 1}"] = t
            res.titles[f"simple_effects_{i + 1}"] = (
                f"Simple effects of {s.effect} at each {s.by}: the {label(s.dv, s.where)}"
                f"{rows(s.dv, s.where)}")
            for _, row in t.iterrows():
                res.sentences.append(
                    f"Simple effect of {row['effect']} at {s.by} = {row[s.by]}"
                    f"{rows(s.dv, s.where)} "
                    f"({row['method']} error term): F({_df(row['df1'])}, {_df(row['df2'])}) = "
                    f"{_fixed(row['F'])}, {format_p(row['p'])}"
                    + (f", η²p = {_num2(row['pes'])}, "
                       f"{eta2p_interval(row['F'], row['df1'], row['df2'])}"
                       if row["method"] == "separate" else "")
                    + ".")
        for i, p in enumerate(spec.posthoc):
            within = p.within or factors
            m = participant_measures(_subset(sub, p.where), p.dv, within + p.between)
            t = attempt(f"The paired comparisons of {p.factor}", pairwise_tests, m, p.dv,
                        within, "participant", factor=p.factor, by=p.by, padjust=p.padjust,
                        between=p.between, error=p.error)
            if t is None:
                continue
            T[f"posthoc_{i + 1}"] = t
            res.titles[f"posthoc_{i + 1}"] = (
                f"Paired comparisons of {p.factor}" + (f" at each {p.by}" if p.by else "")
                + f": the {label(p.dv, p.where)}{rows(p.dv, p.where)}")
        for i, o in enumerate(spec.ordinal):
            m = participant_measures(_subset(sub, o.where), o.dv, [o.factor])
            fr = attempt(f"The Friedman test of {o.factor}", friedman, m, o.dv, o.factor,
                         "participant")
            if fr is None:
                continue
            what = f"{label(o.dv, o.where)}{rows(o.dv, o.where)}"
            T[f"friedman_{i + 1}"] = fr
            res.titles[f"friedman_{i + 1}"] = f"Friedman test of {o.factor}: the {what}"
            wx = attempt(f"The Wilcoxon comparisons of {o.factor}", wilcoxon_pairwise, m, o.dv,
                         o.factor, "participant", padjust=o.padjust)
            if wx is not None:      # a Friedman test that ran is kept when these cannot
                T[f"wilcoxon_{i + 1}"] = wx
                res.titles[f"wilcoxon_{i + 1}"] = (f"Wilcoxon signed-rank comparisons of "
                                                   f"{o.factor}: the {what}")
            r = fr.iloc[0]
            res.sentences.append(
                f"Friedman test of {o.factor} on the {what}: χ²({_df(r['df'])}, "
                f"N = {int(r['n'])}) = {_fixed(r['Q'])}, {format_p(r['p'])}, Kendall's W = "
                f"{_num2(r['kendall_W'])}.")

    if spec.confusion is not None and scored:
        by = spec.confusion.by
        loaded = mine[-1].meta.get("experiment_loaded", {})
        first = loaded.get("question") or (loaded.get("questions") or [{}])[0]
        labels = list((first or {}).get("options", [])) or None
        T["confusion"] = confusion_matrix(sub, by, labels=labels)
        T["information_transfer"] = information_transfer(sub, by, labels=labels)
        T["agreement"] = agreement(sub, by, labels=labels)
        T["information_transfer_all"] = information_transfer(sub, labels=labels)
        T["agreement_all"] = agreement(sub, labels=labels)
    adaptive = loaded.get("adaptive")
    if adaptive:
        ps = spec.psychometric or PsychometricSpec()
        done_est: set = set()
        fits, points = psychometric_fits(sub, adaptive, function=ps.function, guess=ps.guess,
                                         lapse=ps.lapse, max_lapse=ps.max_lapse,
                                         bootstrap=ps.bootstrap, by=ps.by)
        T["psychometric_fit"] = fits
        T["psychometric_points"] = points
        res.titles["psychometric_fit"] = (f"Psychometric function of {adaptive['variable']} "
                                          "per participant (maximum likelihood)")
        res.titles["psychometric_points"] = (f"Answers counted as yes at each level of "
                                             f"{adaptive['variable']} played")
        est = procedure_estimates(sub, adaptive, loaded.get("factors") or {})
        T["procedure_estimates"] = est
        res.titles["procedure_estimates"] = (
            f"The procedure's own estimate of {adaptive['variable']} per participant and "
            "track (recomputed by replaying the log)")
        many_tracks = est["track"].nunique() > 1 if len(est) else False
        for _, row in fits.iterrows():
            res.sentences.append(fit_sentence(row, adaptive["variable"], ps.by))
            mine_est = est[est["participant"] == row["participant"]] if len(est) else est
            for _, e in mine_est.iterrows():
                if e.name in done_est:
                    continue
                done_est.add(e.name)
                res.sentences.append(estimate_sentence(
                    e, adaptive["variable"], track=many_tracks,
                    session=mine_est["session"].nunique() > 1))
    if spec.mixed_model is not None and scored:
        mf = spec.mixed_model.factors or factors
        try:
            with warnings.catch_warnings(record=True) as w:
                warnings.simplefilter("always", MixedModelWarning)
                g = mixed_logit(sub, mf, interactions=spec.mixed_model.interactions,
                                items=spec.mixed_model.items, n_quad=spec.mixed_model.n_quad)
            T["mixed_model"] = g
            notes.append(f"Mixed logistic model: {g.attrs['formula']}; {g.attrs['method']}; "
                         "Wald z tests and 95 % intervals; reference levels "
                         + ", ".join(f"{k} = {v}" for k, v in g.attrs["reference_levels"].items())
                         + f"; {g.attrs['n_trials']} trials of {g.attrs['n_participants']} "
                         "participants.")
            res.warnings.extend(str(x.message) for x in w)
        except (InputError, np.linalg.LinAlgError, ValueError) as e:
            notes.append(f"the mixed logistic model could not be fitted: {e}")
    for w in caught:
        msg = str(w.message)
        if msg not in res.warnings:
            res.warnings.append(msg)
    return res


def recognition_table(trials: pd.DataFrame, rows: str, columns: str, *,
                      pooled: bool = True) -> pd.DataFrame:
    """Rate by ``rows`` × ``columns`` with a mean column (seed 001 Table 1 layout).

    With ``pooled`` (the paper's way) each cell is correct / scored trials over
    all participants, and ``mean`` the pooled rate of the row; otherwise each
    cell is the mean of the participants' rates.
    """
    scored = trials[trials["correct"].notna()].assign(
        correct=lambda d: d["correct"].astype(float))
    if pooled:
        t = scored.pivot_table(index=rows, columns=columns, values="correct", aggfunc="mean",
                               observed=True)
        t["mean"] = scored.groupby(rows, observed=True)["correct"].mean()
    else:
        per = recognition_rates(scored, [rows, columns], per_participant=True)
        t = per.pivot_table(index=rows, columns=columns, values="rate", aggfunc="mean",
                            observed=True)
        t["mean"] = recognition_rates(scored, [rows], per_participant=True) \
            .groupby(rows, observed=True)["rate"].mean()
    t.columns = [str(c) for c in t.columns]
    t = t.reset_index()
    t[rows] = t[rows].astype(str)
    return t
