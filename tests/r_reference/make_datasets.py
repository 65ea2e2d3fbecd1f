"""Write the datasets that the R reference scripts and the tests both read.

Run once (the CSVs are committed; rerunning rewrites the same files):

    python tests/r_reference/make_datasets.py

Each dataset is drawn from numpy's PCG64 generator with a fixed seed, so this
script reproduces the committed files byte for byte.

| file | design | why |
|---|---|---|
| oneway_sphericity.csv | 1 factor, 4 levels, 12 participants, one row per cell | variances 1 : 4 : 16 : 36 and unequal correlations: Mauchly's test rejects sphericity, GG and HF differ |
| seed000_2x2.csv | timing (fixed, varied) × intensity (linear, nonlinear), 15 participants, rate of 10 trials per cell | the layout of seed 000 §4 (modes 3–6); cell totals 76, 71, 112, 79 of 150 reproduce the paper's 50.7, 47.3, 74.7, 52.7 % |
| grid_3x4.csv | shape (3) × soa (4), 14 participants, one row per cell | a 3 × 4 with sphericity in question for both factors and the interaction |
| threeway.csv | display (2) × timing (3) × intensity (3), 10 participants, two rows per cell | a three-factor within design; afex averages the two rows per cell |
| missing_cell.csv | shape (2) × timing (3), 12 participants, 3 trials (correct 0/1) per cell | participants 04 and 09 lack every trial of one cell; afex drops them with a warning |
| ratings.csv | frequency (25, 40, 50 Hz), 9 participants, ratings 0–4 | ordinal ratings with ties (seed 002's whirlpool scale) for Friedman and Wilcoxon |
| mixed_group_soa.csv | group (blind 7, sighted 9) between × soa (100, 200, 300, 400 ms) within, one row per cell | an unbalanced mixed design: type 3 sums of squares, sphericity in question, a graded factor for trend contrasts |
| mixed_2b2w.csv | group (2) × age (3 bands, observed) between, 4–6 per group × shape (2) × timing (3) within, two rows per cell, one missing value | two between and two within factors, unequal groups, η²G with an observed factor, a participant dropped for a missing value |
| trials_items.csv | display (2) × timing (2), 20 participants × 16 items, correct 0/1 | a mixed logistic model with crossed participant and item intercepts |
| trials_glmm.csv | display (2) × timing (3), 24 participants, 10 trials (correct 0/1) per cell | logistic model with a random intercept (SD 1), for the mixed logistic regression against lme4::glmer |
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pandas as pd

OUT = Path(__file__).resolve().parents[1] / "data"


def pid(i: int) -> str:
    return f"{i + 1:02d}"


def oneway_sphericity() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1001))
    sd = np.array([1.0, 2.0, 4.0, 6.0])
    corr = np.array([[1.0, 0.8, 0.3, 0.0],
                     [0.8, 1.0, 0.5, 0.1],
                     [0.3, 0.5, 1.0, 0.6],
                     [0.0, 0.1, 0.6, 1.0]])
    cov = corr * np.outer(sd, sd)
    mu = np.array([10.0, 11.0, 13.5, 12.0])
    y = rng.multivariate_normal(mu, cov, size=12)
    rows = [(pid(i), lv, round(float(y[i, j]), 4))
            for i in range(12) for j, lv in enumerate(["100", "200", "300", "400"])]
    return pd.DataFrame(rows, columns=["participant", "soa", "rt"])


def seed000_2x2() -> pd.DataFrame:
    # Correct answers out of 10 per participant and mode; totals fixed to the paper's rates.
    rng = np.random.Generator(np.random.PCG64(1002))
    cells = [("fixed", "linear", 76), ("fixed", "nonlinear", 71),
             ("varied", "linear", 112), ("varied", "nonlinear", 79)]
    ability = rng.normal(0, 0.12, size=15)
    rows = []
    for timing, intensity, total in cells:
        p = np.clip(total / 150 + ability, 0.02, 0.98)
        k = rng.binomial(10, p)
        while k.sum() != total:             # move single answers until the total is the paper's
            i = rng.integers(15)
            if k.sum() < total and k[i] < 10:
                k[i] += 1
            elif k.sum() > total and k[i] > 0:
                k[i] -= 1
        rows += [(pid(i), timing, intensity, k[i] / 10) for i in range(15)]
    return pd.DataFrame(rows, columns=["participant", "timing", "intensity", "rate"])


def grid_3x4() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1003))
    shapes, soas = ["triangle", "circle", "square"], ["100", "200", "300", "400"]
    n = 14
    subj = rng.normal(0, 0.6, size=n)
    slope = rng.normal(0, 0.25, size=n)       # participants differ in their soa trend
    rows = []
    for i in range(n):
        for a, s in enumerate(shapes):
            for b, t in enumerate(soas):
                mu = 2.0 + 0.3 * a + 0.2 * b - 0.15 * a * b * (b == 3)
                y = mu + subj[i] + slope[i] * b + rng.normal(0, 0.25 + 0.15 * b)
                rows.append((pid(i), s, t, round(float(y), 4)))
    return pd.DataFrame(rows, columns=["participant", "shape", "soa", "score"])


def threeway() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1004))
    n = 10
    subj = rng.normal(0, 0.1, size=n)
    rows = []
    for i in range(n):
        for (a, disp), (b, tim), (c, inten) in itertools.product(
                enumerate(["static", "dynamic"]), enumerate(["fixed", "varied", "fast"]),
                enumerate(["linear", "nonlinear", "flat"])):
            mu = 0.3 + 0.25 * a + 0.05 * b * a - 0.04 * c + 0.03 * (b == 2) * (c == 1)
            for _ in range(2):
                y = mu + subj[i] + rng.normal(0, 0.08 + 0.04 * c)
                rows.append((pid(i), disp, tim, inten, round(float(y), 4)))
    return pd.DataFrame(rows, columns=["participant", "display", "timing", "intensity", "rate"])


def missing_cell() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1005))
    shapes, timings = ["circle", "square"], ["200/100", "300/200", "300/500"]
    n = 12
    ability = rng.normal(0, 0.8, size=n)
    rows = []
    trial = 0
    for i in range(n):
        for a, s in enumerate(shapes):
            for b, t in enumerate(timings):
                if (pid(i), s, t) in (("04", "square", "300/500"), ("09", "circle", "200/100")):
                    continue                  # the cell's trials were never logged
                logit = -0.5 + 1.5 * (b > 0) + 0.4 * a + ability[i]
                for _ in range(3):
                    trial += 1
                    correct = int(rng.random() < 1 / (1 + np.exp(-logit)))
                    rows.append((pid(i), trial, s, t, correct))
    return pd.DataFrame(rows, columns=["participant", "trial", "shape", "timing", "correct"])


def ratings() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1006))
    n = 9
    rows = []
    for i in range(n):
        base = rng.integers(0, 2)
        for j, f in enumerate(["25", "40", "50"]):
            r = int(np.clip(base + j + rng.integers(-1, 2), 0, 4))
            rows.append((pid(i), f, r))
    return pd.DataFrame(rows, columns=["participant", "frequency", "rating"])


def trials_glmm() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1007))
    rows = []
    for i in range(24):
        u = rng.normal(0, 1)
        for a in ["static", "dynamic"]:
            for b in ["fixed", "slow", "varied"]:
                eta = 0.2 + u + 0.8 * (a == "static") - 0.6 * (b == "slow") + 1.0 * (b == "varied")
                for _ in range(10):
                    rows.append((pid(i), a, b, int(rng.random() < 1 / (1 + np.exp(-eta)))))
    return pd.DataFrame(rows, columns=["participant", "display", "timing", "correct"])


def mixed_group_soa() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1008))
    rows = []
    k = 0
    for group, n in (("blind", 7), ("sighted", 9)):
        for _ in range(n):
            k += 1
            u = rng.normal(0, 0.5)
            slope = rng.normal(0, 0.15)
            for j, soa in enumerate(["100", "200", "300", "400"]):
                mu = 2.0 + 0.5 * (group == "blind") + 0.35 * j - 0.05 * j * j \
                    + 0.15 * j * (group == "blind")
                y = mu + u + slope * j + rng.normal(0, 0.2 + 0.12 * j)
                rows.append((pid(k - 1), group, soa, round(float(y), 4)))
    return pd.DataFrame(rows, columns=["participant", "group", "soa", "score"])


def mixed_2b2w() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1009))
    sizes = {("blind", "18-30"): 5, ("blind", "31-50"): 4, ("blind", "51-70"): 6,
             ("sighted", "18-30"): 6, ("sighted", "31-50"): 5, ("sighted", "51-70"): 4}
    rows = []
    k = 0
    for (group, age), n in sizes.items():
        for _ in range(n):
            k += 1
            u = rng.normal(0, 0.08)
            for a, shape in enumerate(["circle", "square"]):
                for b, timing in enumerate(["fast", "medium", "slow"]):
                    mu = 0.55 + 0.08 * (group == "blind") - 0.04 * (age == "51-70") \
                        + 0.06 * a + 0.05 * b + 0.04 * a * b * (group == "blind")
                    for _ in range(2):
                        y = round(float(mu + u + rng.normal(0, 0.06 + 0.02 * b)), 4)
                        rows.append([pid(k - 1), group, age, shape, timing, y])
    df = pd.DataFrame(rows, columns=["participant", "group", "age", "shape", "timing", "rate"])
    # participant 07 has one of the two values of a cell missing: afex's mean of the cell
    # is missing, and it drops the participant with a message
    cell = df.index[(df["participant"] == "07") & (df["shape"] == "square")
                    & (df["timing"] == "slow")]
    df.loc[cell[0], "rate"] = np.nan
    return df


def trials_items() -> pd.DataFrame:
    rng = np.random.Generator(np.random.PCG64(1010))
    item_u = rng.normal(0, 0.7, size=16)
    rows = []
    for i in range(20):
        u = rng.normal(0, 1.0)
        for j in range(16):
            display = "static" if j % 2 == 0 else "dynamic"
            for timing in ("fixed", "varied"):
                eta = 0.6 + u + item_u[j] + 0.7 * (display == "static") \
                    - 0.5 * (timing == "varied")
                rows.append((pid(i), f"i{j + 1:02d}", display, timing,
                             int(rng.random() < 1 / (1 + np.exp(-eta)))))
    return pd.DataFrame(rows, columns=["participant", "item", "display", "timing", "correct"])


DATASETS = {"oneway_sphericity": oneway_sphericity, "seed000_2x2": seed000_2x2,
            "grid_3x4": grid_3x4, "threeway": threeway, "missing_cell": missing_cell,
            "ratings": ratings, "trials_glmm": trials_glmm, "mixed_group_soa": mixed_group_soa,
            "mixed_2b2w": mixed_2b2w, "trials_items": trials_items}


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name, make in DATASETS.items():
        df = make()
        df.to_csv(OUT / f"{name}.csv", index=False, lineterminator="\n")
        print(f"{OUT / name}.csv: {len(df)} rows")


if __name__ == "__main__":
    main()
