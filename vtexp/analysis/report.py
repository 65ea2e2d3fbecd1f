"""Tables of recognition rates, written as CSV and Markdown and printed."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

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
