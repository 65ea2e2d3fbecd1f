"""Reports: rate tables (CSV, Markdown) and, per experiment, the full report.

The full report (:func:`write_experiment_report`) is one self-contained HTML
file with the figures embedded as base64 PNG, a Markdown twin with the PNGs
beside it, and one CSV per table. It formats an
:class:`~vtexp.analysis.pipeline.ExperimentAnalysis` and computes nothing.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .load import SessionData
from .rates import recognition_rates


def markdown_table(df: pd.DataFrame, floatfmt: str = "{:.3f}") -> str:
    def fmt(v):
        if isinstance(v, float):
            return "" if pd.isna(v) else floatfmt.format(v)
        return "" if v is pd.NA or v is None else str(v)
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(fmt(v) for v in row) + " |")
    return "\n".join(lines)


@dataclass
class RateReport:
    tables: dict[str, pd.DataFrame]
    files: list[Path]
    markdown: Path


def write_rate_report(trials: pd.DataFrame, sessions: list[SessionData], out: Path
                      ) -> RateReport:
    """Rates per condition, per factor and per participant, for each experiment."""
    out.mkdir(parents=True, exist_ok=True)
    tables: dict[str, pd.DataFrame] = {}
    files: list[Path] = []
    md = ["# Recognition rates", ""]
    trials_csv = out / "trials.csv"
    trials.to_csv(trials_csv, index=False)
    files.append(trials_csv)
    for exp in sorted(trials["experiment"].unique()):
        sub = trials[trials["experiment"] == exp]
        factors = next(s.factors for s in sessions if s.meta["experiment"] == exp)
        title = next(s.meta["experiment_loaded"]["title"] for s in sessions
                     if s.meta["experiment"] == exp)
        n_part = sub["participant"].nunique()
        md += [f"## {exp}", "", f"{title}. {n_part} participant(s), {len(sub)} trials.", ""]
        parts = {"by_condition": factors, **{f"by_{f}": [f] for f in factors}}
        for key, by in parts.items():
            t = recognition_rates(sub, by)
            tables[f"{exp}/{key}"] = t
            f = out / f"{exp}_rates_{key}.csv"
            t.to_csv(f, index=False)
            files.append(f)
            md += [f"### Rate {key.replace('_', ' ')}", "",
                   markdown_table(t.drop(columns="experiment")), ""]
        per = recognition_rates(sub, factors, per_participant=True)
        tables[f"{exp}/by_participant"] = per
        f = out / f"{exp}_rates_by_participant.csv"
        per.to_csv(f, index=False)
        files.append(f)
        overall = recognition_rates(sub, [], per_participant=True)
        md += ["### Rate by participant (all conditions)", "",
               markdown_table(overall.drop(columns="experiment")), ""]
    warnings = [w for s in sessions for w in s.warnings]
    if warnings:
        md += ["## Warnings", ""] + [f"- {w}" for w in warnings] + [""]
    md_path = out / "report.md"
    md_path.write_text("\n".join(md), encoding="utf-8")
    files.append(md_path)
    return RateReport(tables, files, md_path)


# --------------------------------------------------------------------------- full report

_PERCENT_TABLES = ("rates_by", "recognition_table")
_LABELS = {"df1": "df1", "df2": "df2", "F": "F", "p": "p", "pes": "η²p",
           "pes_ci90_low": "η²p 90% CI low", "pes_ci90_high": "η²p 90% CI high", "ges": "η²G",
           "dz_ci95_low": "dz 95% CI low", "dz_ci95_high": "dz 95% CI high",
           "mauchly_W": "Mauchly W", "mauchly_p": "Mauchly p", "eps_gg": "ε GG",
           "p_gg": "p GG", "eps_hf": "ε HF", "p_hf": "p HF", "n": "n"}

_CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; color: #222;
       line-height: 1.45; padding: 0 1em; }
table { border-collapse: collapse; margin: 0.6em 0 1.2em; font-size: 0.88em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.55em; text-align: right; }
th { background: #f0f3f7; }
td:first-child, th:first-child { text-align: left; }
.alarm { border: 3px solid #c00; background: #fee; padding: 0.6em 1em; margin: 1em 0; }
.alarm h2 { color: #c00; margin-top: 0.2em; }
.note { color: #555; font-size: 0.9em; }
img { max-width: 100%; }
.tablewrap { overflow-x: auto; max-width: 100%; }
td.na { color: #777; font-style: italic; }
ul.apa li { margin: 0.2em 0; }
"""


NOT_APPLICABLE = "n/a"

EFFECT_SIZE_NOTE = (
    "Intervals of effect sizes: η²p has a two-sided 90% interval from the noncentral F "
    "distribution (Steiger 2004; it excludes 0 exactly when the F test's p < .05), in the "
    "tables on the df of the table and in the sentences on the df printed there (corrected "
    "by ε where a correction is named); dz has a two-sided 95% interval from the noncentral "
    "t distribution. Both as R's effectsize package computes them "
    "(vtexp/analysis/effect_sizes.py).")


def _cell(v, col: str, percent: bool) -> str:
    if v is None or v is pd.NA or (isinstance(v, float) and np.isnan(v)):
        # an undefined measure is never a number (the reason is in the table's
        # not_applicable column or the note under it)
        return NOT_APPLICABLE
    if isinstance(v, (float, np.floating)) and np.isinf(v):
        return NOT_APPLICABLE
    if isinstance(v, (float, np.floating)):
        if percent and col not in ("n_trials", "n_correct", "n_participants", "n"):
            return f"{v * 100:.1f}%"
        if col in ("p", "p_gg", "p_hf", "p_adj", "mauchly_p"):
            return "< .001" if v < 0.001 else f"{v:.3f}"
        if col in ("df1", "df2", "df") and abs(v - round(v)) < 1e-9:
            return f"{v:.0f}"
        return f"{v:.3f}"
    return str(v)


def _display(name: str, df: pd.DataFrame) -> tuple[pd.DataFrame, bool]:
    percent = name.startswith(_PERCENT_TABLES)
    if name.startswith(("anova", "simple_effects")):
        df = df.drop(columns=[c for c in ("SS", "SS_error", "MSE") if c in df.columns])
    return df, percent


def html_table(name: str, df: pd.DataFrame) -> str:
    df, percent = _display(name, df)
    head = "".join(f"<th>{html.escape(_LABELS.get(str(c), str(c)))}</th>" for c in df.columns)
    body = []
    for row in df.itertuples(index=False):
        body.append("<tr>" + "".join(
            f"<td>{html.escape(_cell(v, str(c), percent and str(c) in _rate_cols(df)))}</td>"
            for v, c in zip(row, df.columns)) + "</tr>")
    return (f"<div class='tablewrap'><table><thead><tr>{head}</tr></thead>"
            f"<tbody>{''.join(body)}</tbody></table></div>")


def _rate_cols(df: pd.DataFrame) -> set[str]:
    return {c for c in df.columns if c not in ("n_trials", "n_correct", "n_participants", "n")
            and pd.api.types.is_float_dtype(df[c])}


def md_table(name: str, df: pd.DataFrame) -> str:
    df, percent = _display(name, df)
    rc = _rate_cols(df) if percent else set()
    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(_LABELS.get(c, c) for c in cols) + " |",
             "|" + "|".join("---" for _ in cols) + "|"]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(_cell(v, c, c in rc) for v, c in zip(row, cols)) + " |")
    return "\n".join(lines)


_SECTIONS = [
    ("rates_by_condition", "Recognition rate per condition (mean of participants ± SE)"),
    ("recognition_table", "Recognition rate by {rows} and {columns}"),
    ("rates_by_participant", "Recognition rate per participant (all conditions)"),
    ("anova", "Repeated-measures ANOVA"),
    ("simple_effects", "Simple effects"),
    ("posthoc", "Paired comparisons"),
    ("friedman", "Friedman test"),
    ("wilcoxon", "Wilcoxon signed-rank comparisons"),
    ("information_transfer", "Information transfer (bits) per condition"),
    ("agreement", "Accuracy and Cohen's kappa per condition"),
    ("mixed_model", "Mixed-effects logistic regression (log-odds)"),
]


def _title_of(key: str, a) -> str:
    if key in a.titles:
        return a.titles[key]
    for prefix, title in _SECTIONS:
        if key == prefix or key.startswith(prefix + "_"):
            if a.spec.table:
                title = title.format(rows=a.spec.table.rows, columns=a.spec.table.columns)
            suffix = key[len(prefix):].lstrip("_")
            return title + (f" ({suffix})" if suffix and suffix[0].isdigit() and
                            suffix != "1" else "")
    return key.replace("_", " ")


def write_experiment_report(a, out: Path) -> dict[str, Path]:
    """The report of one experiment: ``report.html`` (self-contained, figures as
    base64 PNG), ``report.md`` with the PNGs beside it, and one CSV per table.

    ``a`` is an :class:`~vtexp.analysis.pipeline.ExperimentAnalysis`; this
    function formats it and computes nothing.
    """
    from . import figures       # with SciPy: md_table ('vtexp stats') does without

    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    for key, df in a.tables.items():
        f = out / f"{key}.csv"
        df.to_csv(f, index=False)
        files[key] = f
    sessions_csv = out / "sessions.csv"
    a.sessions.to_csv(sessions_csv, index=False)
    files["sessions"] = sessions_csv

    figs: list[tuple[str, str, bytes]] = []
    T = a.tables
    for i, fd in enumerate(a.figures):
        if fd.key not in T or T[fd.key].empty:
            continue
        m = T[fd.key].copy()
        for col in [fd.x] + ([fd.trace] if fd.trace else []):
            m[col] = pd.Categorical(m[col].astype(str),
                                    categories=[str(v) for v in a.levels.get(col, [])] or None)
        what = fd.label[:1].upper() + fd.label[1:]
        n = f"_{i + 1}" if i else ""
        figs.append((f"rates{n}", f"{what}{fd.where_text} by {fd.x}"
                     + (f" and {fd.trace}" if fd.trace else "") + " (mean ± SE across "
                     "participants)",
                     figures.rate_by_condition(m, fd.dv, fd.x, fd.trace, fd.label,
                                               scale=fd.scale)))
        figs.append((f"participants{n}", f"{what}{fd.where_text} by {fd.x}, one line per "
                     "participant" + (f", one panel per {fd.trace}" if fd.trace else ""),
                     figures.per_participant_lines(m, fd.dv, fd.x, fd.label, trace=fd.trace,
                                                   scale=fd.scale)))
    if "psychometric_fit" in T and not T["psychometric_fit"].empty:
        ps = a.spec.psychometric
        variable = a.titles.get("psychometric_fit", "").removeprefix(
            "Psychometric function of ").split(" per participant")[0] or "level"
        figs.append(("psychometric", f"Psychometric function per participant: proportion of "
                     f"yes by {variable} played, the maximum-likelihood fit and the threshold "
                     "with its 95 % bootstrap interval",
                     figures.psychometric_curves(T["psychometric_fit"], T["psychometric_points"],
                                                 variable, ps.by if ps else [])))
    if "confusion" in T:
        figs.append(("confusion", "Confusion matrices (rows: shape presented; columns: "
                     "answer; % of the row)",
                     figures.confusion_heatmaps(T["confusion"], a.spec.confusion.by)))
    for name, _, png in figs:
        f = out / f"figure_{name}.png"
        f.write_bytes(png)
        files[f"figure_{name}"] = f

    mismatch = a.sessions[a.sessions["checksum"] == "MISMATCH"]
    unclosed = a.sessions[a.sessions["status"] != "completed"]
    order = [k for k in T if k not in ("confusion", "information_transfer_all",
                                       "agreement_all")
             and not k.startswith("figure_per_participant")
             and not (k.startswith("rates_by_") and k not in ("rates_by_condition",
                                                              "rates_by_participant"))]

    # ---- HTML
    h = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(a.title)}"
         f"</title><style>{_CSS}</style></head><body>",
         f"<h1>{html.escape(a.title)}</h1>",
         f"<p>{html.escape(a.experiment)} — {html.escape(a.reference)}. {a.n_participants} "
         f"participant(s), {a.n_trials} trials (practice excluded). Analyses: "
         f"{html.escape(a.spec_source)}.</p>"]
    if len(mismatch):
        h.append("<div class='alarm'><h2>Checksum mismatch</h2><p>These sessions' files changed "
                 "after the session ended; the results below include them as they are now:</p>"
                 "<ul>" + "".join(f"<li>{html.escape(r.folder)}</li>"
                                  for r in mismatch.itertuples()) + "</ul></div>")
    h.append("<h2>Sessions</h2>" + html_table("sessions", a.sessions))
    if len(unclosed):
        h.append(f"<p class='note'>{len(unclosed)} session(s) did not complete; every trial "
                 "they logged is included.</p>")
    if a.warnings:
        h.append("<ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in a.warnings) + "</ul>")
    if a.sentences:
        h.append("<h2>Results</h2><ul class='apa'>"
                 + "".join(f"<li>{html.escape(s)}</li>" for s in a.sentences) + "</ul>")
    for name, caption, png in figs:
        if name == "confusion":
            continue
        h.append(f"<h2>{html.escape(caption)}</h2><img alt='{name}' src='data:image/png;base64,"
                 f"{base64.b64encode(png).decode()}'>")
    for key in order:
        h.append(f"<h2>{html.escape(_title_of(key, a))}</h2>" + html_table(key, T[key]))
        if key.startswith("information_transfer"):
            h.append("<p class='note'>IT is the maximum-likelihood estimate from the pooled "
                     "confusion matrix; it is biased upwards with few trials, by about "
                     "(k−1)²/(2N ln 2) bits (bias_bits; Miller 1955), and IT_corrected "
                     "subtracts it. Trust it when n ≥ 5k² (n_recommended; Houtsma 1983).</p>")
    for name, caption, png in figs:
        if name == "confusion":
            h.append(f"<h2>{html.escape(caption)}</h2><img alt='{name}' src='data:image/png;"
                     f"base64,{base64.b64encode(png).decode()}'>")
    if a.notes:
        h.append("<h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in a.notes)
                 + "</ul>")
    h.append("<p class='note'>n/a: not applicable — the measure is undefined there (the "
             "reason is in the row's not_applicable column; Mauchly's test and ε need an "
             "effect with more than one df; dz needs paired values).</p>")
    h.append(f"<p class='note'>{html.escape(EFFECT_SIZE_NOTE)}</p>")
    h.append("<p class='note'>Repeated-measures ANOVA on participants' cell means (afex::aov_ez "
             "conventions: Mauchly's test, Greenhouse–Geisser and Huynh–Feldt ε, partial and "
             "generalised η²). Simple effects: 'separate' = one ANOVA per level with its own "
             "error term; 'pooled' = the full model's error terms with Satterthwaite df "
             "(emmeans::joint_tests on the univariate model). Paired comparisons: Holm-corrected "
             "unless stated. Made by vtexp.</p></body></html>")
    html_path = out / "report.html"
    html_path.write_text("\n".join(h), encoding="utf-8")
    files["html"] = html_path

    # ---- Markdown
    md = [f"# {a.title}", "",
          f"{a.experiment} — {a.reference}. {a.n_participants} participant(s), {a.n_trials} "
          f"trials (practice excluded). Analyses: {a.spec_source}.", ""]
    if len(mismatch):
        md += ["> **CHECKSUM MISMATCH** — these sessions' files changed after the session "
               "ended; the results include them as they are now:", ">"]
        md += [f"> - {r.folder}" for r in mismatch.itertuples()] + [""]
    md += ["## Sessions", "", md_table("sessions", a.sessions), ""]
    if a.warnings:
        md += [f"- {w}" for w in a.warnings] + [""]
    if a.sentences:
        md += ["## Results", ""] + [f"- {s}" for s in a.sentences] + [""]
    for name, caption, _ in figs:
        md += [f"## {caption}", "", f"![{name}](figure_{name}.png)", ""]
    for key in order:
        md += [f"## {_title_of(key, a)}", "", md_table(key, T[key]), ""]
    if a.notes:
        md += ["## Notes", ""] + [f"- {n}" for n in a.notes] + [""]
    md += [EFFECT_SIZE_NOTE, ""]
    md_path = out / "report.md"
    md_path.write_text("\n".join(md), encoding="utf-8")
    files["markdown"] = md_path
    return files


def write_reports(trials: pd.DataFrame, sessions: list[SessionData], out: Path, *,
                  specs: dict | None = None) -> tuple[RateReport, dict[str, dict]]:
    """Rate tables for all experiments (``out/report.md``) and, per experiment, the
    full report in ``out/<experiment>/`` (HTML, Markdown, CSV).

    ``specs`` maps an experiment name to an ``AnalysisSpec`` that replaces the
    one recorded in its sessions. Returns, per experiment, its files and (key
    ``analysis``) the :class:`~vtexp.analysis.pipeline.ExperimentAnalysis`.
    """
    from .pipeline import analyse_experiment        # likewise

    rates = write_rate_report(trials, sessions, out)
    full: dict[str, dict] = {}
    for exp in sorted(trials["experiment"].unique()):
        a = analyse_experiment(trials, sessions, exp, spec=(specs or {}).get(exp))
        full[exp] = {**write_experiment_report(a, out / exp), "analysis": a}
    with open(rates.markdown, "a", encoding="utf-8") as f:
        f.write("\n## Full reports\n\n")
        for exp in full:
            f.write(f"- {exp}: [{exp}/report.html]({exp}/report.html), "
                    f"[{exp}/report.md]({exp}/report.md)\n")
    return rates, full
