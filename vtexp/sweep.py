"""Power surfaces: ``vtexp simulate EXPERIMENT --sweep FILE``.

A sweep file varies what a study's power depends on, the number of participants and
anything in the experiment file, and the power of every declared effect is simulated
at each combination::

    participants: [8, 12, 16, 24]         # N per study
    studies: 500                          # per point (default: --studies)
    vary:                                 # experiment keys, dotted; each a list of values
      design.repetitions: [1, 2, 4]
      coding.params.duration_ms: [200, 300]

``repetitions: [...]`` at the top is short for ``vary: {design.repetitions: [...]}``.
Each combination of ``vary`` values is a variant of the experiment file (its YAML with
those keys set), checked like any experiment before the first study runs, and sent to
the workers as text with its SHA-256. Every point uses the same seed and study numbers,
so the designs are compared on the same simulated participants (common random numbers):
differences between points come from the design, not from drawing other people.
"""

from __future__ import annotations

import itertools
from copy import deepcopy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import yaml
from pydantic import ConfigDict, Field, ValidationError

from .errors import InputError
from .model import Model
from .simulate import ExperimentSource, PowerResult, prepared, run_power
from .yamlio import format_validation_error, load_yaml


class SweepSpec(Model):
    """The sweep file (unknown keys refused)."""

    model_config = ConfigDict(extra="forbid")

    participants: list[int] = Field(min_length=1, description="N per study, each ≥ 2")
    studies: int | None = Field(None, ge=1, description="studies per point")
    repetitions: list[int] | None = Field(None, min_length=1,
                                          description="short for vary: design.repetitions")
    vary: dict[str, list[Any]] = Field(default_factory=dict,
                                       description="dotted experiment key → values")


@dataclass
class SweepPoint:
    setting: dict[str, Any]          # dotted key → value
    source: ExperimentSource


def load_sweep(path: Path | str) -> tuple[SweepSpec, Any]:
    doc = load_yaml(path)
    if not isinstance(doc.data, dict):
        raise InputError("expected a mapping (participants:, vary:, ...)", path=str(path), line=1)
    try:
        spec = SweepSpec.model_validate(doc.data)
    except ValidationError as e:
        raise format_validation_error(e, doc) from None
    for n in spec.participants:
        if n < 2:
            raise InputError("a study needs at least 2 participants", path=str(path),
                             line=doc.line_of(("participants",)), key="participants")
    if spec.repetitions is not None:
        if "design.repetitions" in spec.vary:
            raise InputError("repetitions is given twice (also under vary)", path=str(path),
                             line=doc.line_of(("repetitions",)), key="repetitions")
        spec.vary = {"design.repetitions": spec.repetitions, **spec.vary}
    for k, values in spec.vary.items():
        if not values:
            raise InputError("give at least one value", path=str(path),
                             line=doc.line_of(("vary", k)), key=f"vary.{k}")
    return spec, doc


def set_key(data: Any, dotted: str, value: Any) -> None:
    """Set ``a.b.c`` in the experiment's data (a number indexes a list; a missing
    mapping is made, and the experiment's schema then refuses a key it does not know)."""
    parts = dotted.split(".")
    node = data
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise KeyError(f"{'.'.join(parts[:i])} has no item {part}")
            if last:
                node[int(part)] = value
            else:
                node = node[int(part)]
        elif isinstance(node, dict):
            if last:
                node[part] = value
            else:                       # made if missing: the schema refuses a wrong key
                node = node.setdefault(part, {})
        else:
            raise KeyError(f"{'.'.join(parts[:i])} is not a mapping or a list")


def sweep_points(experiment: Path | str, spec: SweepSpec, sweep_doc, *, params_file=None
                 ) -> list[SweepPoint]:
    """Every variant of the experiment the sweep asks for, each loaded and checked."""
    base = load_yaml(experiment)
    keys = list(spec.vary)
    points = []
    for values in itertools.product(*(spec.vary[k] for k in keys)):
        setting = dict(zip(keys, values))
        data = deepcopy(base.data)
        for k, v in setting.items():
            try:
                set_key(data, k, v)
            except KeyError as e:
                raise InputError(str(e).strip("'\""), path=str(sweep_doc.path),
                                 line=sweep_doc.line_of(("vary", k)), key=f"vary.{k}") from None
        text = base.text if not setting else yaml.safe_dump(data, sort_keys=False,
                                                            allow_unicode=True)
        source = ExperimentSource.of(experiment, params_file=params_file, text=text)
        try:
            prepared(source)                # wrong values: one message before any study
        except InputError as e:
            where = ", ".join(f"{k} = {v}" for k, v in setting.items())
            raise InputError(f"with {where}: {e.message}", path=str(sweep_doc.path),
                             key=f"vary.{keys[0]}" if keys else None) from None
        points.append(SweepPoint(setting, source))
    return points


def run_sweep(points: list[SweepPoint], participants: list[int], studies: int, *,
              alpha: float = 0.05, seed: int = 0, workers: int = 1, executor=None,
              on_point=None) -> pd.DataFrame:
    """The power surface: one row per (point, N, effect) with power, its interval, the
    median p and mean η²p."""
    rows = []
    for point in points:
        for n in participants:
            res: PowerResult = run_power(point.source.path, n, studies, alpha=alpha, seed=seed,
                                         workers=workers, executor=executor,
                                         source=point.source)
            if on_point is not None:
                on_point(point, n, res)
            for r in res.table.to_dict(orient="records"):
                rows.append({**point.setting, "participants": n, **r})
    return pd.DataFrame(rows)


def surface_lines(table: pd.DataFrame, keys: list[str]) -> list[str]:
    """The power surface as text: a row per design point and N, a column per effect."""
    if table.empty:
        return ["the experiment declares no test, so there is no power to estimate"]
    effects = list(dict.fromkeys(table["effect"]))
    cols = [*keys, "participants"]
    wide = table.pivot_table(index=cols, columns="effect", values="power", sort=False)
    wide = wide.reindex(columns=effects)
    names = [k.rsplit(".", 1)[-1] if sum(x.rsplit(".", 1)[-1] == k.rsplit(".", 1)[-1]
                                           for x in keys) == 1 else k for k in keys]
    width = [max(len(str(h)), 6) for h in [*names, "N"]]
    head = "  ".join(f"{h:>{w}}" for h, w in zip([*names, "N"], width))
    head += "  " + "  ".join(f"{f'[{i + 1}]':>6}" for i in range(len(effects)))
    lines = ["effects:", *(f"  [{i + 1}] {e}" for i, e in enumerate(effects)), "", head]
    for idx, r in wide.iterrows():
        idx = idx if isinstance(idx, tuple) else (idx,)
        cells = "  ".join(f"{str(v):>{w}}" for v, w in zip(idx, width))
        lines.append(cells + "  " + "  ".join(f"{p:6.3f}" for p in r.to_numpy()))
    return lines
