"""What a session's files hold: the columns of its logs, its BIDS sidecars, and the
content of its session record (``..._session.json``)."""

from __future__ import annotations

import functools
import os
import platform
import sys
from importlib import metadata
from pathlib import Path

from .. import __version__, bids
from ..clock import Clock, iso
from ..experiment import LoadedExperiment
from ..log import sha256_file

FORMAT_VERSION = 2     # 2: the BIDS layout (record in sourcedata/vtexp/)

EVENT_COLUMNS = ["onset", "duration", "trial", "play", "row", "col", "scheduled_onset_ms", "onset_ms",
                 "duration_ms", "level", "amplitude_v", "frequency_hz", "pulse_width_ms"]


def trial_columns(factors: list[str], camera: bool = False, adaptive: bool = False
                  ) -> list[str]:
    """The trial log's columns; ``stim_file`` after ``stimulus`` with camera stimuli,
    ``proposed`` and ``presented`` with an adaptive procedure."""
    return (["trial", "practice", "repetition", "block", *factors, "stimulus",
             *(["stim_file"] if camera else []),
             *(["proposed", "presented"] if adaptive else []), "question",
             "answer", "correct_answer", "correct", "rt_s", "replays", "stimulus_onset_ms",
             "stimulus_duration_ms", "n_pulses", "status", "started_at"])


def has_camera(lx: LoadedExperiment) -> bool:
    return any(s.is_camera for s in lx.experiment.stimuli.values())


def log_columns(lx: LoadedExperiment) -> list[str]:
    """The trial log's columns for this experiment."""
    return trial_columns(list(lx.experiment.factors), has_camera(lx),
                         lx.experiment.adaptive is not None)


def task_fields(lx: LoadedExperiment) -> dict:
    """What BIDS asks of every task sidecar (``_beh.json``, ``_events.json``)."""
    exp = lx.experiment
    return {"TaskName": exp.task_label, "TaskFullName": exp.title,
            "TaskDescription": exp.description.strip() or exp.title,
            "Instructions": exp.instructions.strip() or exp.asked()[0].prompt,
            "StimulusPresentation": {
                "SoftwareName": "vtexp", "SoftwareVersion": __version__,
                "OperatingSystem": f"{platform.system()} {platform.release()}".strip(),
                "Code": bids.CODE_URL},
            "vtexpTask": exp.name}


def _factor_columns(exp) -> dict[str, dict]:
    return {name: {"Description": f.description or f"level of factor '{name}'",
                   "Levels": {lv: (f"sets {f.sets} parameters {f.params_of(lv)}"
                                   if f.params_of(lv) else lv) for lv in f.level_names}}
            for name, f in exp.factors.items()}


def _optional_columns(lx: LoadedExperiment) -> dict[str, dict]:
    """The adaptive procedure's and the camera's columns, when the experiment has them."""
    exp = lx.experiment
    cols: dict[str, dict] = {}
    if exp.adaptive is not None:
        cols["proposed"] = {"Description": f"the level of {exp.adaptive.variable} the adaptive "
                                           f"procedure ({exp.adaptive.procedure.kind}) asked "
                                           "for, from the answers before this trial"}
        cols["presented"] = {"Description": f"the level of {exp.adaptive.variable} played: the "
                                            "nearest the device can play to the one proposed"}
    if has_camera(lx):
        cols["stim_file"] = {"Description": "camera stimuli: the frame taken at the trial (PNG), "
                                            "relative to the session's record folder "
                                            "sourcedata/vtexp/sub-<P>/ses-<N>/; a live trial's "
                                            "record is the folder of the same name + '-live'"}
    return cols


def sidecar(lx: LoadedExperiment) -> dict:
    """The BIDS ``_beh.json``: what each column means."""
    exp = lx.experiment
    cols: dict[str, dict] = {
        "trial": {"Description": "trial number in the session, from 1"},
        "practice": {"Description": "1 for a practice trial (not analysed), else 0"},
        "repetition": {"Description": "presentation number of this condition, from 1 "
                                      "(0 for practice trials)"},
        "block": {"Description": "block number with a blocked design, else 0"},
        **_factor_columns(exp),
        "stimulus": {"Description": "name of the stimulus in the experiment file"},
        **_optional_columns(lx),
        "question": {"Description": "name of the question answered (one row per question)",
                     "Levels": {q.name: q.prompt for q in exp.asked()}},
        "answer": _answer_description(exp.asked()),
        "correct_answer": {"Description": "the option scored as correct, n/a if unscored"},
        "correct": {"Description": "1 if answer equals correct_answer, 0 if not, n/a if "
                                   "unscored"},
        "rt_s": {"Description": "reaction time from the end of the stimulus",
                 "Units": "s"},
        "replays": {"Description": "times the participant felt the stimulus again"},
        "stimulus_onset_ms": {"Description": "device clock at the stimulus onset",
                              "Units": "ms"},
        "stimulus_duration_ms": {"Description": "duration of the played schedule",
                                 "Units": "ms"},
        "n_pulses": {"Description": "number of actuator pulses in the stimulus"},
        "status": {"Description": "ok, skipped, device_error, or stopped (an adaptive track "
                                  "had met its stop rule: nothing was played)"},
        "started_at": {"Description": "wall-clock start of the trial, ISO 8601"},
    }
    # BIDS: TaskName is the task label of the file names; the title is TaskFullName.
    return {**task_fields(lx), **cols}


def _answer_description(questions: list) -> dict:
    if len(questions) > 1:
        return {"Description": "the answer to the row's question: "
                + "; ".join(f"{q.name}: " + _answer_description([q])["Description"]
                            for q in questions)}
    q = questions[0]
    if q.kind == "rating":
        return {"Description": f"the rating, from {q.low} to {q.high}",
                "Levels": {str(v): q.labels.get(v, str(v)) for v in q.scale}}
    if q.kind == "number":
        return {"Description": f"the number given, from {q.minimum} to {q.maximum}"}
    return {"Description": "the option chosen", "Levels": {o: o for o in q.options}}


def events_sidecar(lx: LoadedExperiment) -> dict:
    """The BIDS ``_events.json``: the task, and what each column of the device events means."""
    return {**task_fields(lx), **{c: dict(bids.EVENTS_SIDECAR[c]) for c in EVENT_COLUMNS}}


def environment() -> dict:
    """What ran the session: vtexp, Python, the platform and the versions of the packages
    its results depend on."""
    return {"vtexp": __version__, "python": sys.version.split()[0],
            "platform": platform.platform(), "machine": platform.machine(),
            "hostname": platform.node(), "packages": dict(_packages())}


@functools.cache
def _packages() -> tuple[tuple[str, str], ...]:
    """The installed versions, read once per process (reading them scans every installed
    distribution's metadata: a few milliseconds each time)."""
    found = []
    for name in ("numpy", "pandas", "pydantic", "PyYAML", "statsmodels", "pyserial",
                 "opencv-contrib-python-headless", "opencv-python", "psychopy"):
        try:
            found.append((name, metadata.version(name)))
        except metadata.PackageNotFoundError:
            pass
    return tuple(found)


def process() -> dict:
    """This process, as a record names the one that ran (or resumed) a session."""
    return {"pid": os.getpid(), "host": platform.node()}


def new_record(setup, info, responder, clock: Clock) -> dict:
    """A new session record: what produced the session (``setup``: a
    :class:`~vtexp.session.options.SessionSetup`; ``info``: the device's
    :class:`~vtexp.model.DeviceInfo`), with status ``running``."""
    lx, paths, exp = setup.lx, setup.paths, setup.lx.experiment
    return {
        "format": "vtexp-session", "format_version": FORMAT_VERSION,
        "experiment": exp.name, "task": exp.task_label, "participant": paths.participant,
        "session": paths.session, "status": "running", "started_at": iso(clock),
        "ended_at": None, "seed": setup.seed,
        "seed_source": "design.seed" if exp.design.seed is not None
        else "derived from (experiment, participant, session)",
        "n_trials_planned": len(setup.trials),
        "trial_order": [t.condition.index for t in setup.trials],
        "conditions": [{"index": c.index, "levels": c.levels, "stimulus": c.stimulus,
                        "encoding": c.encoding_params, "coding": c.coding_params}
                       for c in setup.conditions],
        "experiment_file": {"path": str(Path(lx.path).resolve()), "sha256": lx.sha256,
                            "text": lx.source.text},
        "stimulus_files": stimulus_files(lx),
        "experiment_loaded": exp.model_dump(mode="json"),
        "device": info.model_dump(mode="json"),
        "device_profile": setup.profile.model_dump(mode="json"),
        "responder": getattr(responder, "description", type(responder).__name__),
        **setup.run_info,
        "process": process(),
        "command": setup.options.command or sys.argv,
        "environment": environment(),
        # Paths from the dataset's root (the record is in sourcedata/vtexp/sub-P/ses-N/).
        "layout": "bids", "bids_version": bids.BIDS_VERSION,
        "files": {"beh": paths.relative(paths.beh_tsv), "sidecar": paths.relative(paths.beh_json),
                  "events": paths.relative(paths.events_tsv),
                  "events_sidecar": paths.relative(paths.events_json)},
        "acquisition_start": None,
        "checksums": None, "n_trials_logged": 0, "reason": None, "resumes": [],
        # proposed/presented written with repr (every digit), so a resume compares them
        # exactly; sessions without this key wrote them rounded to 6 decimals.
        **({"adaptive_levels": "exact"} if exp.adaptive is not None else {}),
    }


def exact_level(v: float | None) -> str | None:
    """A level as the log keeps it: every digit (``repr``), so that it reads back equal."""
    return None if v is None else repr(float(v))


def stimulus_files(lx: LoadedExperiment) -> dict[str, dict[str, str]]:
    """The image and video files the experiment's stimuli are read from: path and SHA-256,
    by stimulus name (what a reader of the data years later needs to find them again)."""
    out = {}
    for name, spec in lx.experiment.stimuli.items():
        f = spec.file or spec.video
        if f is not None:
            p = lx.resolve(f)
            out[name] = {"path": str(p.resolve()), "sha256": sha256_file(p)}
    return out
