"""Time per 15-participant 2 × 2 repeated-measures ANOVA: vtexp against pingouin and statsmodels.

- single: one dataset, one call (``vtexp.analysis.rm_anova``,
  ``pingouin.rm_anova``, ``statsmodels.stats.anova.AnovaRM(...).fit()``), the
  median of repeated calls.
- batch: N datasets (default 10,000) stacked in one tidy table with a
  ``dataset`` column, as a power analysis produces them. vtexp analyses them
  all with ``rm_anova_batch`` (one vectorised numpy pass; the time includes
  reshaping the table); pingouin and statsmodels have no batch form, so they
  are called once per dataset on a sample of the datasets (default 300; ``--full``
  runs all N, about 10 minutes) and the time per analysis is the mean.

The numbers are compared on every dataset both libraries analysed: F, p and
SS against pingouin (also generalised η² = pingouin's ng2) and F and p against
statsmodels; the goal is agreement to 1e-9. Ratios are pingouin's and
statsmodels' time per analysis over vtexp's, in the same run.

Prints a table and writes JSON to bench/results/stats.json.
Usage: python bench/stats.py [--datasets N] [--sample K] [--full] [--seed S]
(needs the ``bench`` extra: pip install -e '.[bench]').
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.analysis.anova import rm_anova, rm_anova_batch  # noqa: E402

N_SUBJECTS = 15
EFFECTS = ["A", "B", "A:B"]


def simulate(n_sets: int, seed: int) -> pd.DataFrame:
    """Rates of 15 participants in a 2 × 2 (10 trials per cell), like seed 000's modes 3–6."""
    rng = np.random.default_rng(seed)
    p = np.array([0.507, 0.473, 0.747, 0.527])                    # seed 000 Fig. 11, modes 3–6
    ability = rng.normal(0, 0.1, size=(n_sets, N_SUBJECTS, 1))
    k = rng.binomial(10, np.clip(p + ability, 0.01, 0.99))          # (sets, subjects, 4)
    rate = (k / 10).ravel()
    sets = np.repeat(np.arange(n_sets), N_SUBJECTS * 4)
    subj = np.tile(np.repeat([f"s{i:02d}" for i in range(N_SUBJECTS)], 4), n_sets)
    a = np.tile(["a1", "a1", "a2", "a2"], n_sets * N_SUBJECTS)
    b = np.tile(["b1", "b2", "b1", "b2"], n_sets * N_SUBJECTS)
    return pd.DataFrame({"dataset": sets, "subject": subj, "A": a, "B": b, "rate": rate})


def timed(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def pingouin_table(d: pd.DataFrame) -> pd.DataFrame:
    import pingouin as pg
    t = pg.rm_anova(d, dv="rate", within=["A", "B"], subject="subject")
    return t


def statsmodels_table(d: pd.DataFrame) -> pd.DataFrame:
    from statsmodels.stats.anova import AnovaRM
    return AnovaRM(d, "rate", "subject", within=["A", "B"]).fit().anova_table


def max_diff(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    both_nan = np.isnan(a) & np.isnan(b)
    return float(np.max(np.where(both_nan, 0.0, np.abs(a - b)))) if a.size else 0.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", type=int, default=10_000)
    ap.add_argument("--sample", type=int, default=300,
                    help="datasets given to pingouin and statsmodels one by one")
    ap.add_argument("--full", action="store_true", help="give them all the datasets")
    ap.add_argument("--seed", type=int, default=20261122)
    ap.add_argument("--repeat", type=int, default=30, help="repeats of the single-call timing")
    args = ap.parse_args()
    try:
        import pingouin
    except ImportError:
        print("bench/stats.py needs pingouin: pip install -e '.[bench]'", file=sys.stderr)
        return 2
    import statsmodels

    warnings.filterwarnings("ignore")
    data = simulate(args.datasets, args.seed)
    one = data[data["dataset"] == 0]

    # ---- single analysis
    single = {
        "vtexp": timed(lambda: rm_anova(one, "rate", ["A", "B"], "subject"), args.repeat),
        "pingouin": timed(lambda: pingouin_table(one), args.repeat),
        "statsmodels": timed(lambda: statsmodels_table(one), args.repeat),
    }

    # ---- batch
    rm_anova_batch(data[data["dataset"] < 10], "rate", ["A", "B"], "subject", "dataset")  # warm
    t0 = time.perf_counter()
    batch = rm_anova_batch(data, "rate", ["A", "B"], "subject", "dataset")
    vt_batch = (time.perf_counter() - t0) / args.datasets
    k = args.datasets if args.full else min(args.sample, args.datasets)
    sample_ids = np.linspace(0, args.datasets - 1, k).round().astype(int)
    groups = {s: g for s, g in data[data["dataset"].isin(sample_ids)].groupby("dataset")}
    diffs = {"pingouin": {"F": 0.0, "p": 0.0, "SS": 0.0, "ges": 0.0},
             "statsmodels": {"F": 0.0, "p": 0.0}}
    pg_time = sm_time = 0.0
    for s in sample_ids:
        g = groups[s]
        ours = batch[batch["dataset"] == s]
        t = time.perf_counter()
        pt = pingouin_table(g)
        pg_time += time.perf_counter() - t
        t = time.perf_counter()
        st = statsmodels_table(g)
        sm_time += time.perf_counter() - t
        for key, col in (("F", "F"), ("p", "p-unc" if "p-unc" in pt else "p_unc"),
                         ("SS", "SS"), ("ges", "ng2")):
            ourcol = {"F": "F", "p": "p", "SS": "SS", "ges": "ges"}[key]
            diffs["pingouin"][key] = max(diffs["pingouin"][key],
                                         max_diff(ours[ourcol], pt[col]))
        diffs["statsmodels"]["F"] = max(diffs["statsmodels"]["F"],
                                        max_diff(ours["F"], st["F Value"]))
        diffs["statsmodels"]["p"] = max(diffs["statsmodels"]["p"],
                                        max_diff(ours["p"], st["Pr > F"]))
    per = {"vtexp": vt_batch, "pingouin": pg_time / k, "statsmodels": sm_time / k}

    worst = max(v for d in diffs.values() for v in d.values())
    rows = [
        ("vtexp rm_anova", single["vtexp"], None),
        ("pingouin.rm_anova", single["pingouin"], single["pingouin"] / single["vtexp"]),
        ("statsmodels AnovaRM", single["statsmodels"],
         single["statsmodels"] / single["vtexp"]),
        (f"vtexp rm_anova_batch ({args.datasets} datasets)", per["vtexp"], None),
        (f"pingouin.rm_anova, one by one ({k} datasets)", per["pingouin"],
         per["pingouin"] / per["vtexp"]),
        (f"statsmodels AnovaRM, one by one ({k} datasets)", per["statsmodels"],
         per["statsmodels"] / per["vtexp"]),
    ]
    print(f"15-participant 2 x 2 repeated-measures ANOVA, time per analysis "
          f"(numpy {np.__version__}, pandas {pd.__version__}, pingouin {pingouin.__version__}, "
          f"statsmodels {statsmodels.__version__})")
    print(f"{'':52} {'ms/analysis':>12} {'x vtexp':>9}")
    for i, (name, t, ratio) in enumerate(rows):
        if i == 0:
            print("single dataset")
        if i == 3:
            print("batch")
        print(f"  {name:50} {t * 1000:12.4f} {('' if ratio is None else f'{ratio:9.1f}'):>9}")
    print(f"largest difference on the {k} datasets compared: "
          + "; ".join(f"{lib} " + ", ".join(f"{q} {v:.1e}" for q, v in d.items())
                      for lib, d in diffs.items())
          + f"  -> {'identical to 1e-9' if worst <= 1e-9 else 'DIFFERS beyond 1e-9'}")
    goal = per["pingouin"] / per["vtexp"]
    print(f"goal >= 50x faster than pingouin per analysis in batch: {goal:.0f}x "
          f"({'met' if goal >= 50 else 'NOT met'})")

    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    result = {
        "benchmark": "rm_anova 2x2, 15 participants",
        "datasets": args.datasets, "compared_datasets": int(k), "seed": args.seed,
        "seconds_per_analysis": {
            "single": single,
            "batch": per,
        },
        "ratios_vs_vtexp": {
            "single": {lib: single[lib] / single["vtexp"] for lib in ("pingouin", "statsmodels")},
            "batch": {lib: per[lib] / per["vtexp"] for lib in ("pingouin", "statsmodels")},
        },
        "max_abs_difference": diffs,
        "identical_to_1e-9": worst <= 1e-9,
        "versions": {"python": platform.python_version(), "numpy": np.__version__,
                     "pandas": pd.__version__, "pingouin": pingouin.__version__,
                     "statsmodels": statsmodels.__version__},
        "machine": platform.machine(), "platform": platform.platform(),
    }
    (out / "stats.json").write_text(json.dumps(result, indent=2) + "\n")
    print(f"written: {out / 'stats.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
