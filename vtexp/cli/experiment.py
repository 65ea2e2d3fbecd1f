"""``vtexp validate``, ``vtexp schema`` and ``vtexp plan``: experiment files before a session."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ._io import note, out


def cmd_validate(args) -> int:
    from ..compile import compile_conditions
    from ..design import trial_list
    from ..experiment import load_experiment

    for f in args.files:
        lx = load_experiment(f)
        for msg in lx.notes:
            note(msg)
        conds = compile_conditions(lx)
        exp = lx.experiment
        n = len(conds) * exp.design.repetitions
        if exp.adaptive is None:
            out(f"{f}: OK — {exp.name}: {len(conds)} conditions x {exp.design.repetitions} "
                f"repetitions = {n} trials per session on {exp.device}; every stimulus within "
                "the device's safety limits")
            continue
        a = adaptive_plan(lx, conds, trial_list(exp, conds, "01", 1)[0])
        out(f"{f}: OK — {exp.name}: {a.describe()} on {exp.device}; "
            f"{exp.adaptive.variable} at {a.n_levels} levels, every one within the device's "
            "safety limits")
    return 0


class AdaptivePlan:
    """What an adaptive session can play: the trials each track may run, and the
    stimulation time if every one of them played the shortest or the longest level."""

    def __init__(self, lx, conditions, trials):
        from ..adaptive.spec import value_list
        from ..adaptive.track import AdaptiveRun

        exp = lx.experiment
        run = AdaptiveRun(exp.adaptive, conditions, 0, exp.asked()[0].name,
                          exp.design.repetitions)
        self.n_levels = len(value_list(exp.adaptive.values))
        self.kind = exp.adaptive.procedure.kind
        self.caps = {run.names[k]: n for k, n in run.stop_trials.items()}
        self.reversals = {run.names[k]: p.stop.reversals for k, p in run.procedures.items()
                          if getattr(p.stop, "reversals", None)}
        self.n_practice = sum(1 for t in trials if t.practice)
        self.n_planned = len(trials)
        self.playable: list[bool] = []          # per trial: may it play (or is it stopped)
        seen: dict = {}
        for t in trials:
            k = run._key[t.condition.index]
            if t.practice:
                self.playable.append(True)
                continue
            seen[k] = seen.get(k, 0) + 1
            self.playable.append(seen[k] <= run.stop_trials[k])
        self.n_max = sum(self.playable)
        self.short_ms = sum(min(s.duration_ms for s in t.condition.schedules.values())
                            for t, ok in zip(trials, self.playable, strict=True) if ok)
        self.long_ms = sum(max(s.duration_ms for s in t.condition.schedules.values())
                           for t, ok in zip(trials, self.playable, strict=True) if ok)

    def durations(self, trial) -> str:
        d = [s.duration_ms for s in trial.condition.schedules.values()]
        lo, hi = min(d), max(d)
        return f"{lo:.0f}" if lo == hi else f"{lo:.0f}-{hi:.0f}"

    def describe(self) -> str:
        n = len(self.caps)
        per = sorted(set(self.caps.values()))
        each = (f"{per[0]} trials" if len(per) == 1 else
                "/".join(str(v) for v in per) + " trials")
        rev = ", ".join(sorted({str(v) for v in self.reversals.values()}))
        stop = f" (or fewer: a track stops after {rev} reversals)" if rev else ""
        practice = f" + {self.n_practice} practice" if self.n_practice else ""
        return (f"{self.kind}, {n} track{'s' if n != 1 else ''} of at most {each}{stop}"
                f"{practice}: at most {self.n_max} of the {self.n_planned} planned trials "
                f"play per session, " + (
                    f"{_minutes(self.short_ms)} to {_minutes(self.long_ms)} of stimulation "
                    "(every one at the shortest or the longest level)"
                    if _minutes(self.short_ms) != _minutes(self.long_ms) else
                    f"{_minutes(self.long_ms)} of stimulation at any level"))


def _minutes(ms: float) -> str:
    return f"{ms / 60000:.1f} min"


def adaptive_plan(lx, conditions, trials) -> AdaptivePlan:
    return AdaptivePlan(lx, conditions, trials)


def cmd_schema(args) -> int:
    """Write the experiment files' JSON Schema, for editors that complete and check YAML."""
    from ..coding import CODINGS
    from ..encoding import PIPELINES
    from ..experiment import Experiment
    from ..model import available_profiles
    from ..stimuli import GENERATORS

    schema = Experiment.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "vtexp experiment"
    defs = schema.get("$defs", {})
    # The names the registries accept, as enums an editor can offer.
    for model, key, names in (("EncodingSpec", "pipeline", PIPELINES),
                              ("CodingSpec", "protocol", CODINGS),
                              ("StimulusSpec", "generator", GENERATORS)):
        prop = defs.get(model, {}).get("properties", {}).get(key)
        if prop is not None:
            prop.pop("anyOf", None)
            prop.update({"type": "string", "enum": sorted(names)})
    schema["properties"]["device"]["enum"] = available_profiles()
    text = json.dumps(schema, indent=2, ensure_ascii=False) + "\n"
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
        out(f"written: {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def cmd_plan(args) -> int:
    from ..compile import compile_conditions
    from ..design import trial_list
    from ..experiment import load_experiment
    from ..responders.base import correct_answer
    from ..session import check_participant, check_session

    check_participant(args.participant)
    check_session(args.session)
    lx = load_experiment(args.file)
    exp = lx.experiment
    conds = compile_conditions(lx)
    trials, seed = trial_list(exp, conds, args.participant, args.session)
    factors = list(exp.factors)
    a = adaptive_plan(lx, conds, trials) if exp.adaptive is not None else None

    def duration(i: int, t) -> str:
        if t.condition.camera:
            return "camera"
        if a is not None:
            return a.durations(t) if a.playable[i] else "stopped"
        return f"{t.condition.schedule.duration_ms:.0f}"
    cols = ["trial", *factors, "stimulus", "repetition", "correct_answer", "duration_ms"]
    rows = [[str(t.number), *(t.levels[f] for f in factors), t.stimulus, str(t.repetition),
             correct_answer(exp.asked()[0], t) or "n/a", duration(i, t)]
            for i, t in enumerate(trials)]
    if args.format == "tsv":
        out("\t".join(cols))
        for r in rows:
            out("\t".join(r))
        return 0
    head = (f"{exp.name}: participant {args.participant}, session {args.session}, seed {seed} "
            f"({'design.seed' if exp.design.seed is not None else 'derived'}), ")
    if a is not None:
        out(head + a.describe())
        out(f"  duration_ms: the shortest-longest schedule of the {a.n_levels} levels of "
            f"{exp.adaptive.variable}; 'stopped': past its track's last trial, never played")
    else:
        total_ms = sum(t.condition.schedule.duration_ms for t in trials
                       if not t.condition.camera)
        out(head + f"{len(trials)} trials, {total_ms / 60000:.1f} min of stimulation")
    widths = [max(len(c), *(len(r[i]) for r in rows)) for i, c in enumerate(cols)]
    out("  ".join(c.ljust(w) for c, w in zip(cols, widths)).rstrip())
    for r in rows:
        out("  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip())
    return 0


def register(sub) -> None:
    """Add ``validate``, ``schema`` and ``plan`` to the ``vtexp`` parser."""
    s = sub.add_parser("validate", help="check experiment files")
    s.add_argument("files", nargs="+", metavar="FILE")
    s.set_defaults(func=cmd_validate)

    s = sub.add_parser("schema", help="write the JSON Schema of experiment files")
    s.add_argument("--out", metavar="FILE", help="write to FILE instead of standard output")
    s.set_defaults(func=cmd_schema)

    s = sub.add_parser("plan", help="print a participant's trial list")
    s.add_argument("file", metavar="FILE")
    s.add_argument("--participant", "-p", required=True)
    s.add_argument("--session", "-s", type=int, default=1)
    s.add_argument("--format", choices=["table", "tsv"], default="table")
    s.set_defaults(func=cmd_plan)
