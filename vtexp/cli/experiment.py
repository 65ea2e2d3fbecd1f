"""``vtexp validate``, ``vtexp schema`` and ``vtexp plan``: experiment files before a session."""

from __future__ import annotations

import sys
from pathlib import Path

from ._io import out


def cmd_validate(args) -> int:
    from ..compile import compile_conditions
    from ..experiment import load_experiment

    for f in args.files:
        lx = load_experiment(f)
        conds = compile_conditions(lx)
        exp = lx.experiment
        n = len(conds) * exp.design.repetitions
        out(f"{f}: OK — {exp.name}: {len(conds)} conditions x {exp.design.repetitions} "
            f"repetitions = {n} trials per session on {exp.device}; every stimulus within "
            "the device's safety limits")
    return 0


def cmd_schema(args) -> int:
    """Write the experiment files' JSON Schema, for editors that complete and check YAML."""
    import json

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
    cols = ["trial", *factors, "stimulus", "repetition", "correct_answer", "duration_ms"]
    rows = [[str(t.number), *(t.levels[f] for f in factors), t.stimulus, str(t.repetition),
             correct_answer(exp.asked()[0], t) or "n/a",
             "camera" if t.condition.camera else f"{t.condition.schedule.duration_ms:.0f}"]
            for t in trials]
    if args.format == "tsv":
        out("\t".join(cols))
        for r in rows:
            out("\t".join(r))
        return 0
    total_ms = sum(t.condition.schedule.duration_ms for t in trials if not t.condition.camera)
    out(f"{exp.name}: participant {args.participant}, session {args.session}, seed {seed} "
        f"({'design.seed' if exp.design.seed is not None else 'derived'}), {len(trials)} "
        f"trials, {total_ms / 60000:.1f} min of stimulation")
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
