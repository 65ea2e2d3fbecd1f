"""Whole studies of model participants, and the power of an experiment's declared analyses.

``vtexp simulate EXPERIMENT --participants N --studies M`` runs M studies of N
model participants each. Every condition goes through the real pipeline once
(stimulus, encoding, coding, safety check, played on the sim device); each
participant gets the trial list a real session would give them
(:func:`vtexp.design.trial_list`) and answers every trial as
:class:`vtexp.observer.ModelObserver` would in a session (the same uniforms, the
same decision), into a table with the columns of :func:`vtexp.analysis.load.load_sessions`.
The experiment's declared ANOVAs (``rm_anova_batch``, every study at once) and
Friedman tests run on each study; the power of an effect is the share of studies
with p < alpha, with a Wilson 95 % interval. Studies are spread over every core, or
over a Dask cluster (``executor=``, ``vtexp.cluster``): a worker receives the
experiment's text and SHA-256 (:class:`ExperimentSource`), never a path, checks the
hash, and keeps the prepared experiment for the tasks that follow. Every random
number is keyed by (seed, study, participant), so the table is the same whichever
worker ran which study.

An observer file of ``kind: stated`` puts a stated design in the model participant's
place (:class:`StatedSetup`): each participant's measure per condition is drawn from
stated means, SDs and correlations and goes through the same tests, whose power is then
also known exactly (:mod:`vtexp.analysis.exact_power`), a check of all of the above.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from .analysis import exact_power
from .analysis.anova import MissingCellsWarning, rm_anova_batch
from .analysis.ordinal import friedman
from .analysis.pipeline import _subset, participant_measures
from .analysis.spec import AnalysisSpec, default_spec
from .compile import compile_conditions
from .design import trial_list
from .devices.sim import SimDevice
from .errors import InputError
from .experiment import LoadedExperiment, load_experiment, load_experiment_text
from .model import Condition, PlayReport
from .observer.model import ObserverModel, question_columns
from .observer.stated import StatedMeasures, load_stated, stated_kind
from .responders.base import correct_answer


@dataclass
class Setup:
    """An experiment made ready for simulation: conditions compiled and played once."""

    lx: LoadedExperiment
    model: ObserverModel
    conditions: list[Condition]
    played: list[PlayReport]
    spec: AnalysisSpec

    @classmethod
    def load(cls, path: Path | str, *, params_file=None, overrides: dict | None = None,
             lx: LoadedExperiment | None = None) -> Setup | StatedSetup:
        """The experiment made ready; an observer file of ``kind: stated`` gives a
        :class:`StatedSetup` instead (measures drawn from stated means, no model)."""
        lx = lx or load_experiment(path)
        if params_file is not None and stated_kind(params_file):
            return StatedSetup.load(lx, params_file)
        model = ObserverModel.for_experiment(lx, params_file=params_file, overrides=overrides)
        conditions = compile_conditions(lx, model.profile)
        played = []
        with SimDevice(model.profile) as dev:
            for c in conditions:
                played.append(dev.play(c.schedule))
        exp = lx.experiment
        scored = any(q.kind == "choice" and q.correct is not None for q in exp.asked())
        spec = exp.analysis or default_spec(list(exp.factors), exp.stimulus_factor(), scored)
        return cls(lx, model, conditions, played, spec)

    @property
    def factors(self) -> list[str]:
        return list(self.lx.experiment.factors)

    def studies(self, seed: int, studies: list[int], n: int) -> pd.DataFrame:
        """The trials of ``studies`` of ``n`` model participants (:func:`simulate_studies`)."""
        return simulate_studies(self, seed, studies, n)

    def measures(self, trials: pd.DataFrame, dv: str, by: list[str], where: dict
                 ) -> pd.DataFrame:
        """One value of ``dv`` per participant and cell of ``by``, among the trials ``where``."""
        return participant_measures(_subset(trials, where), dv, by)

    def condition_means(self, trials: pd.DataFrame) -> pd.DataFrame:
        return condition_means(self, trials)


def participant_id(study: int, i: int) -> str:
    return f"s{study}p{i + 1}"


def simulate_participant(setup: Setup, seed: int, participant: str, session: int = 1,
                         *, typical: bool = False) -> list[dict]:
    """One participant's main trials, one row per trial and question (as a session logs them)."""
    exp, model = setup.lx.experiment, setup.model
    trials, _ = trial_list(exp, setup.conditions, participant, session)
    who = model.participant(seed, participant, typical=typical)
    U = model.uniforms(seed, participant, session, len(trials))
    questions = exp.asked()
    offsets = np.cumsum([0] + [question_columns(q) for q in questions])
    main = [t for t in trials if not t.practice]
    by_condition: dict[int, list] = {}
    for t in main:
        by_condition.setdefault(t.condition.index, []).append(t)
    answer: dict[tuple[int, int], str] = {}
    for ci, ts in by_condition.items():
        c = ts[0].condition
        idx = np.array([t.number - 1 for t in ts])
        for qi, q in enumerate(questions):
            got = model.answers(q, c, setup.played[ci], who,
                                U[idx, offsets[qi]:offsets[qi + 1]], played_key=("condition", ci))
            for t, a in zip(ts, got, strict=True):
                answer[(t.number, qi)] = a
    rows = []
    for t in main:
        for qi, q in enumerate(questions):
            ans = answer[(t.number, qi)]
            right = correct_answer(q, t) if q.kind == "choice" else None
            rows.append({"participant": participant, **t.levels, "stimulus": t.stimulus,
                         "question": q.name, "trial": t.number, "answer": ans,
                         "correct": None if right is None else float(ans == right)})
    return rows


def simulate_studies(setup: Setup, seed: int, studies: list[int], n: int, *,
                     typical: bool = False) -> pd.DataFrame:
    """The trials of ``studies`` (study numbers) of ``n`` participants each, one table."""
    rows = []
    for s in studies:
        for i in range(n):
            for r in simulate_participant(setup, seed, participant_id(s, i), typical=typical):
                r["study"] = s
                rows.append(r)
    df = pd.DataFrame(rows)
    for f, spec in setup.lx.experiment.factors.items():
        df[f] = pd.Categorical(df[f], categories=spec.level_names, ordered=True)
    return df


# --------------------------------------------------------------------------- tests per study

def effect_label(effect: str, a) -> str:
    """An effect's name in the power table: ``timing × intensity (rate, display = dynamic)``."""
    where = "".join(f", {k} = {v}" for k, v in a.where.items())
    return f"{effect.replace(':', ' × ')} ({a.dv}{where})"


def effect_tests(setup: Setup | StatedSetup, trials: pd.DataFrame) -> pd.DataFrame:
    """p of every declared ANOVA effect and Friedman test, for each study in ``trials``."""
    out = []
    spec = setup.spec
    for i, a in enumerate(spec.anova):
        within = a.within or setup.factors
        m = setup.measures(trials, a.dv, within, a.where)
        m["study"] = m["participant"].map(trials.drop_duplicates("participant")
                                          .set_index("participant")["study"])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MissingCellsWarning)
            warnings.simplefilter("ignore", RuntimeWarning)
            t = rm_anova_batch(m, a.dv, within, "participant", "study")
        # the correction the report uses ('auto': Greenhouse-Geisser when Mauchly's p < .05)
        gg = (t["df1"] > 1) & ~(t["mauchly_p"] >= 0.05) if a.correction == "auto" else \
            pd.Series(a.correction == "GG", index=t.index) & (t["df1"] > 1)
        p = np.where(gg, t["p_gg"], t["p"])
        if a.correction == "HF":
            p = np.where(t["df1"] > 1, t["p_hf"], t["p"])
        out.append(pd.DataFrame({
            "study": t["study"], "test": f"anova {i + 1}",
            "effect": [effect_label(e, a) for e in t["effect"]],
            "p": p, "pes": t["pes"]}))
    for i, o in enumerate(spec.ordinal):
        m = setup.measures(trials, o.dv, [o.factor], o.where)
        where = "".join(f", {k} = {v}" for k, v in o.where.items())
        for s, ms in m.groupby(trials.drop_duplicates("participant").set_index("participant")
                               ["study"].reindex(m["participant"]).to_numpy()):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    p = float(friedman(ms, o.dv, o.factor, "participant").iloc[0]["p"])
                except (InputError, ValueError):
                    p = float("nan")
            out.append(pd.DataFrame({"study": [s], "test": f"friedman {i + 1}",
                                     "effect": [f"{o.factor} (Friedman, {o.dv}{where})"],
                                     "p": [p], "pes": [float("nan")]}))
    return pd.concat(out, ignore_index=True) if out else pd.DataFrame(
        columns=["study", "test", "effect", "p", "pes"])


def condition_means(setup: Setup, trials: pd.DataFrame) -> pd.DataFrame:
    """Sums behind the predicted mean per condition and question (rate, or numeric answer)."""
    t = trials.copy()
    t["value"] = np.where(t["correct"].notna(), t["correct"],
                          pd.to_numeric(t["answer"], errors="coerce"))
    t["measure"] = np.where(t["correct"].notna(), "rate", "mean answer")
    g = t.groupby(["question", "measure", *setup.factors], observed=True)["value"]
    return g.agg(total="sum", count="count").reset_index()


# --------------------------------------------------------------------------- stated designs

def _reads(where: dict, question: str) -> bool:
    """Whether a test's ``where`` keeps the trials of ``question`` (or selects no question)."""
    v = where.get("question")
    return v is None or v == question or (isinstance(v, list) and question in v)


@dataclass
class StatedSetup:
    """An experiment whose participants' measures are drawn from a stated design.

    ``--observer FILE`` with ``kind: stated`` (:mod:`vtexp.observer.stated`): each
    participant's measure in each condition is drawn from the stated multivariate
    normal, and the experiment's declared tests run on it exactly as on model
    participants' rates or ratings (the same ``rm_anova_batch``, corrections, Friedman
    tests, Wilson intervals and N search). No pipeline runs and no trial is simulated;
    a participant's table has one row per condition, its measure in ``value``. The
    power of the declared ANOVAs is then also known exactly (:meth:`exact`).
    """

    lx: LoadedExperiment
    stated: StatedMeasures
    spec: AnalysisSpec

    @classmethod
    def load(cls, lx: LoadedExperiment, params_file) -> StatedSetup:
        stated = load_stated(params_file, lx)
        exp = lx.experiment
        scored = any(q.kind == "choice" and q.correct is not None for q in exp.asked())
        spec = exp.analysis or default_spec(list(exp.factors), exp.stimulus_factor(), scored)
        setup = cls(lx, stated, spec)
        q = setup.question           # only the tests of the question the means are of
        setup.spec = spec.model_copy(update={
            "anova": [a for a in spec.anova if _reads(a.where, q)],
            "ordinal": [o for o in spec.ordinal if _reads(o.where, q)]})
        return setup

    @property
    def factors(self) -> list[str]:
        return list(self.lx.experiment.factors)

    @property
    def question(self) -> str:
        """The question whose measure is stated (the file's, or the experiment's first)."""
        return self.stated.question or self.lx.experiment.asked()[0].name

    def studies(self, seed: int, studies: list[int], n: int) -> pd.DataFrame:
        """``n`` participants of each study: one row per participant and condition."""
        k = len(self.stated.conditions)
        x = np.concatenate([self.stated.draw(seed, s, n) for s in studies])
        df = pd.DataFrame({
            "study": np.repeat(studies, n * k),
            # numbers, not names: unique in the chunk, and far quicker to group by
            "participant": np.repeat(np.arange(len(studies) * n), k),
            "condition": np.tile(np.arange(k), n * len(studies)), "value": x.ravel()})
        for f, spec in self.lx.experiment.factors.items():
            levels = np.array([c[f] for c in self.stated.conditions], dtype=object)
            df[f] = pd.Categorical(levels[df["condition"].to_numpy()],
                                   categories=spec.level_names, ordered=True)
        df["question"] = self.question
        return df

    def measures(self, trials: pd.DataFrame, dv: str, by: list[str], where: dict
                 ) -> pd.DataFrame:
        """The stated measure (standing for ``dv``) per participant and cell of ``by``: the
        mean over the conditions in the cell, each condition weighing the same (as each
        condition's trials do in a session with equal repetitions)."""
        t = _subset(trials, where)
        out = (t.groupby(["participant", *by], observed=True, sort=True)["value"]
               .agg(value="mean", n_trials="size").reset_index())
        return out.rename(columns={"value": dv})

    def condition_means(self, trials: pd.DataFrame) -> pd.DataFrame:
        g = trials.groupby(["question", *self.factors], observed=True)["value"]
        out = g.agg(total="sum", count="count").reset_index()
        out.insert(1, "measure", "stated measure")
        return out

    # ------------------------------------------------------------------ exact power
    def exact_designs(self) -> list[tuple[int, object, exact_power.ExactDesign]]:
        """For each declared ANOVA (its index, spec), the stated design it analyses: the
        conditions its ``where`` keeps, averaged over the factors it leaves out, as
        :meth:`measures` averages them (a linear map ``A``: means ``A μ``, covariance
        ``A Σ Aᵀ``, exactly those of the averaged measures)."""
        exp = self.lx.experiment
        conds = self.stated.conditions
        out = []
        for i, a in enumerate(self.spec.anova):
            within = a.within or self.factors
            keep = [j for j, c in enumerate(conds)
                    if all(c[f] == v or (isinstance(v, list) and c[f] in v)
                           for f, v in a.where.items() if f in exp.factors)]
            levels = {f: [lv for lv in exp.factors[f].level_names
                          if any(conds[j][f] == lv for j in keep)] for f in within}
            cells = list(itertools.product(*levels.values()))
            A = np.zeros((len(cells), len(conds)))
            for ci, cell in enumerate(cells):
                members = [j for j in keep if tuple(conds[j][f] for f in within) == cell]
                if not members:
                    raise InputError(
                        "no condition has " + ", ".join(f"{f} = {v}" for f, v in
                                                        zip(within, cell))
                        + f", so the ANOVA of {' × '.join(within)} has an empty cell",
                        path=str(self.lx.path), key=f"analysis.anova.{i}")
                A[ci, members] = 1.0 / len(members)
            design = exact_power.ExactDesign(levels, A @ self.stated.means,
                                             A @ self.stated.cov @ A.T)
            out.append((i, a, design))
        return out

    def exact(self, n: int, alpha: float = 0.05) -> pd.DataFrame:
        """The exact power of every declared ANOVA effect with ``n`` participants
        (:func:`vtexp.analysis.exact_power.exact_anova`): ``effect`` (named as in the
        power table), ``test``, ``exact_power``, ``df1``, ``df2``, ``lambda``, ``pes``,
        ``correction`` (the declared one: the exact value is for the uncorrected F)."""
        rows = []
        for i, a, design in self.exact_designs():
            t = exact_power.exact_anova(design, n, alpha)
            for _, r in t.iterrows():
                rows.append({"effect": effect_label(r["effect"], a), "test": f"anova {i + 1}",
                             "exact_power": float(r["power"]), "df1": float(r["df1"]),
                             "df2": float(r["df2"]), "lambda": float(r["lambda"]),
                             "pes": float(r["pes"]), "correction": a.correction})
        return pd.DataFrame(rows, columns=["effect", "test", "exact_power", "df1", "df2",
                                           "lambda", "pes", "correction"])

    def exact_smallest_n(self, target: float, alpha: float = 0.05, n_max: int = 200
                         ) -> pd.DataFrame:
        """For each declared ANOVA effect, the smallest N whose exact power reaches
        ``target`` (:func:`vtexp.analysis.exact_power.smallest_n`); None above ``n_max``."""
        rows = []
        for i, a, design in self.exact_designs():
            t = exact_power.smallest_n(design, target, alpha, n_max=n_max)
            for _, r in t.iterrows():
                rows.append({"effect": effect_label(r["effect"], a), "test": f"anova {i + 1}",
                             "smallest_n": None if r["n"] is None or r["n"] != r["n"]
                             else int(r["n"]), "power": float(r["power"])})
        return pd.DataFrame(rows, columns=["effect", "test", "smallest_n", "power"])


# --------------------------------------------------------------------------- workers
@dataclass(frozen=True)
class ExperimentSource:
    """What a worker needs to rebuild an experiment for simulation, as text.

    ``path`` only names the file in messages (and is where files it refers to are
    looked for); the experiment is ``text``, checked against ``sha256`` where it is
    loaded. ``observer_text`` is the observer parameter file's text (None: the
    shipped defaults), ``overrides`` a JSON text of parameter overrides.
    """

    text: str
    sha256: str
    path: str
    observer_text: str | None = None
    observer_path: str | None = None
    overrides: str = "{}"

    @classmethod
    def of(cls, path: Path | str, *, params_file=None, overrides: dict | None = None,
           text: str | None = None) -> ExperimentSource:
        if text is None:
            try:
                text = Path(path).read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as e:
                raise InputError(f"cannot read: {e}", path=str(path)) from None
        obs = None
        if params_file is not None:
            try:
                obs = Path(params_file).read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as e:
                raise InputError(f"cannot read: {e}", path=str(params_file)) from None
        return cls(text, hashlib.sha256(text.encode("utf-8")).hexdigest(), str(path), obs,
                   None if params_file is None else str(params_file),
                   json.dumps(overrides or {}, sort_keys=True))

    @property
    def key(self) -> str:
        return hashlib.sha256("\0".join((self.sha256, self.observer_text or "",
                                          self.overrides)).encode("utf-8")).hexdigest()

    def setup(self) -> Setup:
        """Load it (the text checked against its SHA-256 first)."""
        got = hashlib.sha256(self.text.encode("utf-8")).hexdigest()
        if got != self.sha256:
            raise InputError(f"the experiment text received has SHA-256 {got[:12]}..., not "
                             f"{self.sha256[:12]}... as sent: it was damaged on the way",
                             path=self.path)
        lx = load_experiment_text(self.text, self.path)
        overrides = json.loads(self.overrides)
        if self.observer_text is None:
            return Setup.load(self.path, lx=lx, overrides=overrides)
        with tempfile.TemporaryDirectory(prefix="vtexp-observer-") as d:
            f = Path(d) / Path(self.observer_path or "observer.yaml").name
            f.write_text(self.observer_text, encoding="utf-8")
            return Setup.load(self.path, lx=lx, params_file=f, overrides=overrides)


#: Prepared experiments in this process (a worker's), by ExperimentSource.key.
_SETUPS: dict[str, Setup] = {}
_KEEP = 8
_SETUP: Setup | None = None


def _one_blas_thread():
    """Keep numpy's BLAS to one thread in this process: the matrices are small, and a
    BLAS thread pool per worker on top of a worker per core oversubscribes the cores
    (measured: 2 workers took 1.8x as long as 1 process without this)."""
    return threadpool_limits(limits=1, user_api="blas")


def _init(path: str, params_file, overrides) -> None:
    global _SETUP, _LIMIT
    _LIMIT = _one_blas_thread()
    _SETUP = Setup.load(path, params_file=params_file, overrides=overrides)


_LIMIT = None


def _work(args) -> tuple[pd.DataFrame, pd.DataFrame, int]:
    seed, studies, n = args
    trials = _SETUP.studies(seed, studies, n)
    return effect_tests(_SETUP, trials), _SETUP.condition_means(trials), len(studies)


def prepared(source: ExperimentSource) -> Setup:
    """``source.setup()``, kept in this process for the chunks and points that follow."""
    setup = _SETUPS.get(source.key)
    if setup is None:
        while len(_SETUPS) >= _KEEP:        # a sweep's points come one after another
            _SETUPS.pop(next(iter(_SETUPS)))
        setup = _SETUPS[source.key] = source.setup()
    return setup


def work_chunk(source: ExperimentSource, seed: int, studies: list[int], n: int
               ) -> tuple[pd.DataFrame, pd.DataFrame, int]:
    """One chunk of studies on any worker: the experiment from its text (kept for the
    next chunk), BLAS on one thread (the worker's other cores run other chunks)."""
    global _LIMIT
    if _LIMIT is None:
        _LIMIT = _one_blas_thread()
    setup = prepared(source)
    trials = setup.studies(seed, studies, n)
    return effect_tests(setup, trials), setup.condition_means(trials), len(studies)


def wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a proportion k / n (95 % by default)."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


@dataclass
class PowerResult:
    n: int
    studies: int
    alpha: float
    table: pd.DataFrame          # effect, power, ci_low, ci_high, median_p, mean_pes
    means: pd.DataFrame          # predicted mean per condition
    seconds: float


def run_power(path: Path | str, n: int, studies: int, *, alpha: float = 0.05, seed: int = 0,
              workers: int | None = None, params_file=None, overrides: dict | None = None,
              progress=None, first_study: int = 0, executor=None,
              source: ExperimentSource | None = None) -> PowerResult:
    """Simulate ``studies`` studies of ``n`` participants and test each (see module doc).

    ``executor``: a ``concurrent.futures.Executor`` to run the chunks on (a Dask
    cluster's, ``vtexp.cluster.connect(...).get_executor()``) instead of a process per
    core; ``workers`` is then how many run at once there (the chunk size follows it).
    ``source``: the experiment as text (:class:`ExperimentSource`), instead of ``path``.
    """
    if n < 2:
        raise InputError("a study needs at least 2 participants", key="--participants")
    if studies < 1:
        raise InputError("give at least 1 study", key="--studies")
    t0 = time.perf_counter()
    workers = workers or os.cpu_count() or 1
    ids = list(range(first_study, first_study + studies))
    size = max(1, min(50, math.ceil(studies / (workers * 6))))
    chunks = [ids[i:i + size] for i in range(0, len(ids), size)]
    tests, means = [], []
    args = [(seed, c, n) for c in chunks]
    # Load here first: a wrong file or parameter is one clear error, not a broken pool.
    if source is not None:
        setup = prepared(source)
    else:
        setup = Setup.load(path, params_file=params_file, overrides=overrides)
    limit = None
    if executor is not None:
        if source is None:
            source = ExperimentSource.of(path, params_file=params_file, overrides=overrides)
        results = executor.map(work_chunk, *zip(*((source, *a) for a in args)))
        pool = None
    elif workers == 1:
        global _SETUP
        _SETUP = setup
        limit = _one_blas_thread()
        results = map(_work, args)
        pool = None
    elif source is not None:
        pool = ProcessPoolExecutor(workers)
        results = pool.map(work_chunk, *zip(*((source, *a) for a in args)))
    else:
        pool = ProcessPoolExecutor(workers, initializer=_init,
                                   initargs=(str(path), params_file, overrides))
        results = pool.map(_work, args)
    try:
        for t, m, k in results:
            tests.append(t)
            means.append(m)
            if progress is not None:
                progress(k)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
        if limit is not None:
            limit.restore_original_limits()
    tests_df = pd.concat(tests, ignore_index=True)
    rows = []
    for (test, effect), g in tests_df.groupby(["test", "effect"], sort=False):
        valid = g["p"].notna()
        k, m = int((g.loc[valid, "p"] < alpha).sum()), int(valid.sum())
        lo, hi = wilson(k, m)
        rows.append({"effect": effect, "test": test, "power": k / m if m else float("nan"),
                     "ci_low": lo, "ci_high": hi, "studies": m,
                     "median_p": float(g["p"].median()),
                     "mean_pes": float(g["pes"].mean())})
    table = pd.DataFrame(rows)
    mdf = pd.concat(means, ignore_index=True)
    keys = [c for c in mdf.columns if c not in ("total", "count")]
    mdf = mdf.groupby(keys, observed=True, sort=False)[["total", "count"]].sum().reset_index()
    mdf["predicted"] = mdf["total"] / mdf["count"]
    mdf = mdf.drop(columns=["total"]).rename(columns={"count": "trials"})
    return PowerResult(n, studies, alpha, table, mdf, time.perf_counter() - t0)


@dataclass(frozen=True)
class FittedRun:
    """One run of the power range: a fitted parameter at one end of its interval."""

    param: str
    end: str                 # "low" or "high"
    value: float
    centre: float
    overrides: dict


def fitted_runs(params_file, site: str | None = None) -> tuple[list[FittedRun], list[str]]:
    """The runs over an observer file's fitted intervals (its ``fitted:`` section, which
    ``vtexp observer fit`` writes), and the parameters it says were not identified.

    Each fitted parameter is set to its interval's low end, then its high end, the
    others staying at the file's values (the centre): two runs per parameter, fewer
    where an end is the centre itself. No section: no runs. ``site``: the body site
    a fitted two-point threshold is of, when the section does not say.
    """
    from .observer.params import load_params
    if params_file is None or stated_kind(params_file):
        return [], []
    fitted = load_params(params_file).fitted
    if fitted is None:
        return [], []
    runs = []
    for name, v in fitted.params.items():
        for end in ("low", "high"):
            x = getattr(v, end)
            if x == v.centre:
                continue
            if name == "two_point_threshold_mm":
                where = fitted.site or site
                if where is None:
                    continue
                over = {name: {where: x}}
            else:
                over = {name: x}
            runs.append(FittedRun(name, end, x, v.centre, over))
    return runs, list(fitted.not_identified)


def power_range(centre: pd.DataFrame, runs: list[tuple[FittedRun, pd.DataFrame]],
                column: str = "power") -> pd.DataFrame:
    """Each effect's ``column`` at the centre and its range (min, max) over the centre
    and ``runs`` (each a fitted parameter at an end of its interval)."""
    rows = []
    for _, r in centre.iterrows():
        vals = [r[column]] + [t.set_index("effect")[column].get(r["effect"], float("nan"))
                              for _, t in runs]
        vals = [v for v in vals if v == v]
        rows.append({"effect": r["effect"], "centre": r[column],
                     "low": min(vals) if vals else float("nan"),
                     "high": max(vals) if vals else float("nan")})
    return pd.DataFrame(rows, columns=["effect", "centre", "low", "high"])


def smallest_n(path: Path | str, target: float, studies: int, *, alpha: float = 0.05,
               seed: int = 0, n_max: int = 200, workers: int | None = None,
               params_file=None, overrides: dict | None = None, on_step=None,
               executor=None) -> tuple[pd.DataFrame, dict[int, PowerResult]]:
    """For each effect, the smallest N whose simulated power reaches ``target``.

    N doubles from 4 until every effect reaches the target (or ``n_max``), then
    each effect's N is found by bisection between the last N below and the first
    at or above. Each N is simulated once with fresh studies.
    """
    results: dict[int, PowerResult] = {}

    def at(n: int) -> pd.Series:
        if n not in results:
            results[n] = run_power(path, n, studies, alpha=alpha, seed=seed, workers=workers,
                                   params_file=params_file, overrides=overrides,
                                   first_study=n * 1_000_000, executor=executor)
            if on_step:
                on_step(n, results[n])
        return results[n].table.set_index("effect")["power"]

    n = 4
    while True:
        power = at(n)
        if (power >= target).all() or n >= n_max:
            break
        n = min(2 * n, n_max)
    out = []
    for e in at(4).index:
        hi = next((m for m in sorted(results) if at(m)[e] >= target), None)
        if hi is None:
            out.append({"effect": e, "smallest_n": None, "power": float(at(n)[e])})
            continue
        lo = max((m for m in sorted(results) if m < hi and at(m)[e] < target), default=None)
        while lo is not None and hi - lo > 1:
            mid = (lo + hi) // 2
            if at(mid)[e] >= target:
                hi = mid
            else:
                lo = mid
        out.append({"effect": e, "smallest_n": hi, "power": float(at(hi)[e])})
    return pd.DataFrame(out), results
