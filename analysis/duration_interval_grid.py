"""Seed 001 §4.1: Table 1 and the two-way ANOVA, reproduced from logged data.

Usage: python analysis/duration_interval_grid.py DATA_DIR [--out FILE.csv]

DATA_DIR is any folder holding sessions of `duration_interval_grid`
(e.g. data/duration_interval_grid or data/demo). Prints:

1. Table 1 in the paper's layout: one row per duration/interval pair, one
   column per shape and the mean identification rate; rates are pooled over
   the trials of all participants, as the paper's percentages are
   (``vtexp.analysis.pipeline.recognition_table``).
2. The two-way repeated-measures ANOVA (shape × duration/interval) on the
   participants' recognition rates, with sphericity corrections
   (``vtexp.analysis.anova.rm_anova``) and an APA sentence per effect.
3. The ANOVA as the paper's degrees of freedom imply it was run: F(7,288) for
   10 participants is a *between-participants* two-way ANOVA of the 320
   participant × cell rates (error df 320 − 32 = 288), which treats a
   participant's 32 rates as independent. We print it beside the
   repeated-measures one (error df 7 × (n − 1)) so the two can be compared; the
   repeated-measures test is the one the design calls for.

``--out`` writes Table 1 as CSV. ``vtexp analyze`` gives the full report (the
same analyses, declared in the experiment's ``analysis:`` section).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vtexp.analysis import load_sessions  # noqa: E402
from vtexp.analysis.anova import rm_anova  # noqa: E402
from vtexp.analysis.pipeline import apa_anova, participant_measures, recognition_table  # noqa: E402
from vtexp.errors import VtexpError  # noqa: E402

SHAPES = ["triangle", "circle", "square", "rectangle"]


def load(data_dir: Path):
    trials, _ = load_sessions([data_dir])
    trials = trials[trials["experiment"] == "duration_interval_grid"]
    if trials.empty:
        raise VtexpError(f"no duration_interval_grid sessions under {data_dir}")
    return trials


def table_1(data_dir: Path):
    """Table 1 (rows: duration/interval; columns: shapes, mean), and the number of participants."""
    trials = load(data_dir)
    t = recognition_table(trials, "timing", "shape", pooled=True).set_index("timing")
    t = t[[s for s in SHAPES if s in t.columns] + ["mean"]]
    t.index.name = "duration/interval (ms)"
    return t, trials["participant"].nunique()


def anovas(trials):
    """The repeated-measures ANOVA, and the between-participants one the paper's df imply."""
    rates = participant_measures(trials, "rate", ["shape", "timing"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rm = rm_anova(rates, "rate", ["shape", "timing"], "participant")
    import statsmodels.formula.api as smf
    from statsmodels.stats.anova import anova_lm
    between = anova_lm(smf.ols("rate ~ C(shape) * C(timing)", data=rates).fit(), typ=2)
    return rm, between


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data_dir", type=Path)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    try:
        t, n = table_1(args.data_dir)
        rm, between = anovas(load(args.data_dir))
    except VtexpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"Table 1. Recognition rate (%) by shape and duration/interval ({n} participants)")
    print((t * 100).round(1).to_string())
    print("\nTwo-way repeated-measures ANOVA on the participants' recognition rates")
    for _, row in rm.iterrows():
        print(f"  {row['effect']}: {apa_anova(row)[0]}")
    print("\nThe paper's F(7,288) = 42.62 matches a between-participants ANOVA of the "
          "participant x cell rates (residual df = cells x participants - 32):")
    res_df = between.loc["Residual", "df"]
    for name, row in between.drop(index="Residual").iterrows():
        print(f"  {name}: F({row['df']:.0f}, {res_df:.0f}) = {row['F']:.2f}, "
              f"p = {row['PR(>F)']:.3g}")
    if args.out:
        t.to_csv(args.out)
        print(f"written: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
