"""Adaptive procedures: do they converge on a known threshold, and how fast is QUEST+?

Convergence. A model participant of known psychometric function answers yes/no:
Weibull, threshold alpha = 150 ms of SOA, slope beta = 3, lapse 0.02, no guessing
(``vtexp.adaptive.psi``; answers drawn from numpy's PCG64 keyed by SHA-256 of the
procedure and run). Each procedure runs R runs (default 500) of 60 trials on levels
the vest plays (whole ms), and its estimate is compared with the level it aims at:

- ``staircase 1u2d``: Levitt's 1-up-2-down on 10..300 ms in steps of 10, steps 40, 20,
  10 ms after 0, 1, 2 reversals, estimate = mean of the reversals but the first (to an
  even count); it aims at the level where psi = 0.707.
- ``weighted 75%``: Kaernbach's 1-up-1-down, down 10 ms, up 30 ms; aims at psi = 0.75.
- ``QUEST``: flat prior on 10..300 ms, slope, guess and lapse known, next level at the
  posterior mean; estimate = the posterior mean; aims at alpha.
- ``QUEST+``: 59 levels (10..300 ms, step 5) x thresholds 20..280 ms (20) x slopes 1..5
  (5) x lapses 0, 0.02, 0.04; estimate = the posterior mean of alpha.
- ``staircase 1u2d + ML fit``: the 1-up-2-down's trials fitted by maximum likelihood
  (``vtexp.adaptive.fit``, lapse free up to 0.1); aims at alpha.
- baseline ``fixed grid + ML fit``: the method of constant stimuli as seed 001 uses
  it, 8 levels (40..320 ms, 40 apart) x 7 or 8 trials = 60 trials in random order,
  fitted the same way; aims at alpha.

Reported: bias (mean estimate - truth), SD, RMSE (ms), and the RMSE's ratio to the
fixed grid's (below 1: the procedure wastes fewer trials).

Speed. One QUEST+ trial = Bayes' rule with the answer + the expected entropy of every
level + the choice of the next level, on a grid of 50 stimulus levels x 20 thresholds x
5 slopes (one lapse rate: 5,000 likelihoods), and again with 3 lapse rates. vtexp's
closed form (``vtexp.adaptive.questplus``) against, in the same run, the same Bayes
computation written as Watson (2017) states it with numpy (a posterior per level and
answer, its entropy) and as plain Python loops over the grid. Median over trials of
simulated runs. Goal: <= 5 ms per trial.

Prints a table and writes JSON to bench/results/adaptive.json.
Usage: python bench/adaptive.py [--runs R] [--trials N]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.adaptive import (Quest, QuestPlus, QuestPlusRule, QuestRule, Staircase,  # noqa: E402
                            StaircaseRule, fit_psychometric, psi, threshold_at)

ALPHA, BETA, LAPSE = 150.0, 3.0, 0.02


def rng_for(name: str, run: int) -> np.random.Generator:
    seed = int.from_bytes(hashlib.sha256(f"bench-adaptive\x00{name}\x00{run}".encode())
                          .digest()[:16], "big")
    return np.random.Generator(np.random.PCG64(seed))


def answer(rng, x: float) -> bool:
    return bool(rng.random() < psi(x, ALPHA, BETA, 0.0, LAPSE))


def nearest(levels: np.ndarray, x: float) -> float:
    return float(levels[int(np.argmin(np.abs(levels - x)))])


def run_staircase(rule: StaircaseRule, rng, trials: int):
    s = Staircase(rule)
    xs, ys = [], []
    for _ in range(trials):
        x = s.propose()
        y = answer(rng, x)
        s.update(x, y)
        xs.append(x)
        ys.append(y)
    return s.estimate(), xs, ys


def convergence(runs: int, trials: int) -> list[dict]:
    levels5 = np.arange(10.0, 301.0, 5.0)
    stair = StaircaseRule(start=250, steps_down=(40, 20, 10), steps_up=(40, 20, 10), n_up=1,
                          n_down=2, minimum=10, maximum=300)
    weighted = StaircaseRule(start=250, steps_down=(10,), steps_up=(30,), minimum=10,
                             maximum=300)
    qrule = QuestRule(thresholds=tuple(levels5), slope=BETA, guess=0.0, lapse=LAPSE,
                      method="mean")
    qprule = QuestPlusRule(levels=tuple(levels5), thresholds=tuple(np.linspace(20, 280, 20)),
                           slopes=(1.0, 2.0, 3.0, 4.0, 5.0), lapses=(0.0, 0.02, 0.04))
    grid = np.arange(40.0, 321.0, 40.0)
    truth = {"staircase 1u2d": float(threshold_at(0.5 ** 0.5, ALPHA, BETA, 0, LAPSE)),
             "weighted 75%": float(threshold_at(0.75, ALPHA, BETA, 0, LAPSE)),
             "QUEST": ALPHA, "QUEST+": ALPHA, "staircase 1u2d + ML fit": ALPHA,
             "fixed grid + ML fit (baseline)": ALPHA}
    est: dict[str, list[float]] = {k: [] for k in truth}
    secs: dict[str, float] = {k: 0.0 for k in truth}
    for r in range(runs):
        t = time.perf_counter()
        e, xs, ys = run_staircase(stair, rng_for("stair", r), trials)
        secs["staircase 1u2d"] += time.perf_counter() - t
        est["staircase 1u2d"].append(e)
        t = time.perf_counter()
        est["staircase 1u2d + ML fit"].append(
            fit_psychometric(xs, ys, function="weibull", bootstrap=0).threshold)
        secs["staircase 1u2d + ML fit"] += time.perf_counter() - t
        t = time.perf_counter()
        est["weighted 75%"].append(run_staircase(weighted, rng_for("weighted", r), trials)[0])
        secs["weighted 75%"] += time.perf_counter() - t

        t = time.perf_counter()
        q, rng = Quest(qrule), rng_for("quest", r)
        for _ in range(trials):
            x = nearest(levels5, q.propose())
            q.update(x, answer(rng, x))
        est["QUEST"].append(q.estimate())
        secs["QUEST"] += time.perf_counter() - t

        t = time.perf_counter()
        qp, rng = QuestPlus(qprule), rng_for("questplus", r)
        for _ in range(trials):
            x = qp.propose()
            qp.update(x, answer(rng, x))
        est["QUEST+"].append(qp.estimate())
        secs["QUEST+"] += time.perf_counter() - t

        t = time.perf_counter()
        rng = rng_for("grid", r)
        xs = rng.permutation(np.resize(grid, trials))
        ys = [answer(rng, x) for x in xs]
        est["fixed grid + ML fit (baseline)"].append(
            fit_psychometric(xs, ys, function="weibull", bootstrap=0).threshold)
        secs["fixed grid + ML fit (baseline)"] += time.perf_counter() - t
    rows = []
    for k, v in est.items():
        a = np.asarray(v)
        err = a - truth[k]
        rows.append({"procedure": k, "truth": truth[k], "mean": float(a.mean()),
                     "bias": float(err.mean()), "sd": float(a.std(ddof=1)),
                     "rmse": float(np.sqrt(np.mean(err ** 2))), "runs": runs,
                     "trials": trials, "seconds_per_run": secs[k] / runs})
    base = rows[-1]["rmse"]
    for row in rows:
        row["rmse_ratio_to_grid"] = row["rmse"] / base
    return rows


# ----------------------------------------------------------------------------- speed

def as_written_numpy(L: np.ndarray, post: np.ndarray) -> np.ndarray:
    """E[H](x) as Watson (2017) writes it: each level's two posteriors and entropies."""
    out = np.empty(L.shape[0])
    for i in range(L.shape[0]):
        total = 0.0
        for lik in (L[i], 1.0 - L[i]):
            joint = post * lik
            pr = joint.sum()
            p = joint / pr
            nz = p[p > 0]
            total += pr * -(nz * np.log(nz)).sum()
        out[i] = total
    return out


def as_written_loops(L: list[list[float]], post: list[float]) -> list[float]:
    out = []
    for row in L:
        total = 0.0
        for r in (1, 0):
            joint = [p * (lk if r else 1.0 - lk) for p, lk in zip(post, row)]
            pr = sum(joint)
            total += pr * -sum((j / pr) * math.log(j / pr) for j in joint if j > 0)
        out.append(total)
    return out


def speed(n_levels: int, lapses: tuple[float, ...], trials: int, runs: int) -> dict:
    rule = QuestPlusRule(levels=tuple(np.linspace(10, 300, n_levels)),
                         thresholds=tuple(np.linspace(20, 280, 20)),
                         slopes=(1.0, 2.0, 3.0, 4.0, 5.0), lapses=lapses)
    fast, numpy_ms, loops_ms = [], [], []
    for r in range(runs):
        q = QuestPlus(rule)
        rng = rng_for("speed", r)
        x = q.propose()
        for k in range(trials):
            y = answer(rng, x)
            t = time.perf_counter()
            q.update(x, y)
            x = q.propose()
            fast.append(time.perf_counter() - t)
            # the same trial as written, from the same posterior (timed on some trials)
            if k % 10 == 0:
                t = time.perf_counter()
                eh = as_written_numpy(q.L, q.posterior)
                nx = float(q.levels[int(np.argmin(eh))])
                numpy_ms.append(time.perf_counter() - t)
                assert np.allclose(eh, q.expected_entropy(), atol=1e-9) and nx == x
            if k % 20 == 0 and r < 2:
                Ll, pl = q.L.tolist(), q.posterior.tolist()
                t = time.perf_counter()
                as_written_loops(Ll, pl)
                loops_ms.append(time.perf_counter() - t)
    med = statistics.median(fast) * 1e3
    return {"grid": f"{n_levels} x 20 x 5 x {len(lapses)}",
            "n_likelihoods": n_levels * 100 * len(lapses),
            "vtexp_ms_median": med, "vtexp_ms_p99": float(np.percentile(fast, 99)) * 1e3,
            "as_written_numpy_ms": statistics.median(numpy_ms) * 1e3,
            "as_written_loops_ms": statistics.median(loops_ms) * 1e3,
            "ratio_numpy": statistics.median(numpy_ms) * 1e3 / med,
            "ratio_loops": statistics.median(loops_ms) * 1e3 / med,
            "goal_ms": 5.0, "meets_goal": med <= 5.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=500)
    ap.add_argument("--trials", type=int, default=60)
    args = ap.parse_args()
    t0 = time.perf_counter()
    conv = convergence(args.runs, args.trials)
    print(f"Convergence on a known threshold: Weibull alpha = {ALPHA:g} ms, beta = {BETA:g}, "
          f"lapse = {LAPSE:g}; {args.runs} runs x {args.trials} trials")
    print(f"{'procedure':32} {'aims at':>8} {'mean':>8} {'bias':>7} {'SD':>7} {'RMSE':>7} "
          f"{'RMSE/grid':>9} {'ms/run':>7}")
    for r in conv:
        print(f"{r['procedure']:32} {r['truth']:8.1f} {r['mean']:8.1f} {r['bias']:+7.1f} "
              f"{r['sd']:7.1f} {r['rmse']:7.1f} {r['rmse_ratio_to_grid']:9.2f} "
              f"{r['seconds_per_run'] * 1e3:7.1f}")
    sp = [speed(50, (0.02,), args.trials, 20), speed(50, (0.0, 0.02, 0.04), args.trials, 20)]
    print("\nQUEST+ per trial (update + expected entropy of every level + choice), median:")
    print(f"{'grid (levels x thresholds x slopes x lapses)':46} {'vtexp ms':>9} {'p99':>7} "
          f"{'numpy as written':>17} {'ratio':>6} {'loops':>9} {'ratio':>7}")
    for s in sp:
        print(f"{s['grid']:46} {s['vtexp_ms_median']:9.3f} {s['vtexp_ms_p99']:7.3f} "
              f"{s['as_written_numpy_ms']:17.3f} {s['ratio_numpy']:6.0f} "
              f"{s['as_written_loops_ms']:9.2f} {s['ratio_loops']:7.0f}")
    print(f"goal: <= 5 ms per trial: {'met' if all(s['meets_goal'] for s in sp) else 'NOT met'}"
          f"; total {time.perf_counter() - t0:.0f} s")
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "adaptive.json").write_text(json.dumps({
        "convergence": conv, "questplus_speed": sp,
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "numpy": np.__version__}}, indent=2), encoding="utf-8")
    print(f"wrote {out / 'adaptive.json'}")


if __name__ == "__main__":
    main()
