"""Damaged and odd inputs of every kind vtexp reads, made by seeded mutators, and the rule
each case is held to (used by ``tests/test_fuzz.py`` and ``bench/fuzz.py``).

A case starts from a real input (an experiment of ``experiments/``, a coding of
``protocols/codings/``, a photograph, a dataset vtexp wrote, a statistics table of
``tests/data/``, one of them published data) and applies one to three mutations drawn
by ``random.Random(seed)``: a value replaced by one of :data:`NASTY` values, a line or
row deleted or doubled, a key or column renamed, bytes flipped, cut or inserted, a
byte-order mark or CRLF line ends.
The command a user would run on it is run in process (``tests/inprocess.py``), and the
outcome is one of:

- ``refused``: a non-zero exit with ``vtexp: error:`` on stderr and no traceback;
- ``accepted``: exit 0, and the output passes the family's integrity check (an
  experiment or coding runs a two-trial session that logs its trials, their stimuli
  played within :data:`MAX_PLAYED_S` of the session's start; an image
  encodes to a schedule within the device's limits; a dataset's analysis either gives
  the numbers of the undamaged dataset or says on stderr what it found, a warning or
  note the undamaged one does not give);
- ``traceback``: an exception escaped (a bug), ``hang``: no end within the time limit,
  ``silent``: accepted, but the integrity check failed.

The goal is no traceback, hang or silent case in any family.
"""

from __future__ import annotations

import json
import random
import re
import shutil
import subprocess
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from inprocess import run_in_process

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"
CODINGS = ROOT / "protocols" / "codings"
DATA = ROOT / "tests" / "data"

#: values a mutation puts where a value was (YAML scalars and flow collections)
NASTY = ["", "-1", "0", "-0", "1e309", "-1e309", "1e12", "1e-300", ".nan", ".inf", "-.inf",
         "null", "~", "[]", "{}", "[[[[[[1]]]]]]", "yes", "no", "x", "'   '", "0x10",
         "99999999999999999999999999", "1.5", "-2.5", "[1, 2, 3]", "{a: 1}", "'\u0007'",
         "\"\\x00\"", "'é✓'", "'" + "z" * 300 + "'", "!!binary aGk=", "&a [1]", "*a",
         "2026-11-26", "'../../etc/passwd'", "'/dev/zero'"]
#: what a cell of a table becomes
NASTY_CELLS = ["", "NA", "nan", "inf", "-inf", "x", "1e400", "-1", "0", "1.5", "maybe",
               "True", "\"", "a\tb", "99999999999999999999", "\u00a0", "1,5", " 1 "]
OUTCOMES = ("refused", "accepted", "traceback", "hang", "silent")
#: an accepted experiment's first two trials play their stimuli within this (seconds): an
#: SOA of 10^9 ms is damage, however safe each pulse is
MAX_PLAYED_S = 600.0


@dataclass
class Case:
    family: str
    seed: int
    outcome: str = ""
    detail: str = ""
    mutations: list[str] = field(default_factory=list)


# ---------------------------------------------------------------- mutators


def mutate_bytes(data: bytes, rng: random.Random, said: list[str]) -> bytes:
    """Bytes damaged as a disk, a transfer or an editor damages them."""
    b = bytearray(data)
    n = len(b)
    kind = rng.choice(["flip", "cut", "insert", "delete", "zero", "bom", "crlf", "double"])
    i = rng.randrange(max(n, 1))
    if kind == "flip" and n:
        for _ in range(rng.randint(1, 8)):
            j = rng.randrange(n)
            b[j] ^= 1 << rng.randrange(8)
    elif kind == "cut":
        b = b[:i]
    elif kind == "insert":
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
    elif kind == "delete":
        del b[i:i + rng.randint(1, 64)]
    elif kind == "zero":
        b[i:i + rng.randint(1, 64)] = bytes(min(64, n - i))
    elif kind == "bom":
        b[0:0] = b"\xef\xbb\xbf"
    elif kind == "crlf":
        b = bytearray(bytes(b).replace(b"\n", b"\r\n"))
    elif kind == "double":
        b[i:i] = b[i:i + rng.randint(1, 200)]
    said.append(f"bytes:{kind}@{i}")
    return bytes(b)


_VALUE = re.compile(r"^(\s*(?:- )?[\w.\-]+:\s*)(\S.*?)(\s+#.*)?$")


def mutate_yaml(text: str, rng: random.Random, said: list[str]) -> str:
    """A YAML file edited wrongly: a value replaced, a line deleted or doubled, a key
    misspelt, an indentation changed, a flow value's element replaced."""
    lines = text.splitlines(keepends=True)
    body = [k for k, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not body:
        return text
    k = rng.choice(body)
    ln = lines[k]
    kind = rng.choice(["value", "value", "value", "delete", "double", "key", "indent",
                       "inner"])
    m = _VALUE.match(ln.rstrip("\n"))
    if kind == "value" and m:
        lines[k] = m.group(1) + rng.choice(NASTY) + "\n"
    elif kind == "inner" and re.search(r"[\[{]", ln):
        parts = re.split(r"([\[\]{},:])", ln)
        idx = [i for i, p in enumerate(parts) if p.strip() and p not in "[]{},:"]
        if idx:
            parts[rng.choice(idx)] = " " + rng.choice(NASTY)
        lines[k] = "".join(parts)
    elif kind == "delete":
        del lines[k]
    elif kind == "double":
        lines.insert(k, ln)
    elif kind == "key" and m:
        key = m.group(1)
        lines[k] = key.replace(key.strip().rstrip(":").lstrip("- "),
                               key.strip().rstrip(":").lstrip("- ") + "x", 1) + m.group(2) + "\n"
    elif kind == "indent":
        lines[k] = rng.choice(["", " ", "   ", "\t"]) + ln
    else:
        lines[k] = rng.choice(NASTY) + "\n"
        kind = "line"
    said.append(f"yaml:{kind}@{k + 1}")
    return "".join(lines)


def mutate_table(text: str, sep: str, rng: random.Random, said: list[str]) -> str:
    """A table edited wrongly: a cell replaced, a row deleted, doubled or cut, a column
    dropped or renamed, a separator added."""
    rows = text.splitlines()
    if len(rows) < 2:
        return text
    kind = rng.choice(["cell", "cell", "cell", "row", "double", "cut", "column", "header",
                       "separator"])
    r = rng.randrange(1, len(rows))
    cells = rows[r].split(sep)
    if kind == "cell":
        cells[rng.randrange(len(cells))] = rng.choice(NASTY_CELLS)
        rows[r] = sep.join(cells)
    elif kind == "row":
        del rows[r]
    elif kind == "double":
        rows.insert(r, rows[r])
    elif kind == "cut":
        rows[r] = rows[r][:rng.randrange(len(rows[r]) + 1)]
    elif kind == "column":
        c = rng.randrange(len(rows[0].split(sep)))
        rows = [sep.join(x for j, x in enumerate(row.split(sep)) if j != c) for row in rows]
    elif kind == "header":
        head = rows[0].split(sep)
        head[rng.randrange(len(head))] = rng.choice(["", "x", head[0], "subject "])
        rows[0] = sep.join(head)
    else:
        rows[r] = rows[r] + sep + rng.choice(NASTY_CELLS)
    said.append(f"table:{kind}@{r + 1}")
    return "\n".join(rows) + "\n"


def _json_nasty(rng: random.Random):
    return rng.choice([None, "", "abc", -1, 0, 1.5, HUGE if rng.random() < 0.1 else 1e308,
                       [], {}, [1, 2], {"a": None}, True, "../../x", 5])


HUGE = "<a number of 5,000 digits>"        # put in the text after json.dumps


def _dumps(obj) -> str:
    return json.dumps(obj, indent=2).replace(json.dumps(HUGE), "9" * 5000)


def mutate_json(text: str, rng: random.Random, said: list[str]) -> str:
    """A JSON record edited wrongly: a value replaced by another type, a key removed, or
    the value nested deeply."""
    try:
        obj = json.loads(text)
    except (ValueError, RecursionError):       # damaged, or nested deeply by a mutation
        return mutate_bytes(text.encode(), rng, said).decode("utf-8", "replace")
    paths: list[tuple] = []

    def walk(o, p):
        paths.append(p)
        if isinstance(o, dict):
            for k, v in o.items():
                walk(v, p + (k,))
        elif isinstance(o, list):
            for i, v in enumerate(o[:20]):
                walk(v, p + (i,))

    walk(obj, ())
    p = rng.choice(paths[1:] or paths)
    kind = rng.choice(["value", "value", "delete", "deep"])
    if not p:
        obj = _json_nasty(rng)
    else:
        parent = obj
        for key in p[:-1]:
            parent = parent[key]
        if kind == "delete" and isinstance(parent, dict):
            del parent[p[-1]]
        elif kind == "deep":
            v = 1
            for _ in range(rng.choice([50, 2000])):
                v = [v]
            parent[p[-1]] = v
        else:
            parent[p[-1]] = _json_nasty(rng)
            kind = "value"
    said.append(f"json:{kind}:{'.'.join(map(str, p))}")
    if kind == "deep":
        import sys
        old = sys.getrecursionlimit()
        sys.setrecursionlimit(max(old, 10000))
        try:
            return _dumps(obj)
        finally:
            sys.setrecursionlimit(old)
    return _dumps(obj)


def mutate_text(text: str, kind: str, rng: random.Random, said: list[str]) -> str:
    """One to three mutations suited to the file's kind (``yaml``, ``tsv``, ``csv``,
    ``json``), one in five on the bytes instead."""
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        if rng.random() < 0.2:
            text = mutate_bytes(text.encode("utf-8"), rng, said).decode("utf-8", "replace")
        elif kind == "yaml":
            text = mutate_yaml(text, rng, said)
        elif kind in ("tsv", "csv"):
            text = mutate_table(text, "\t" if kind == "tsv" else ",", rng, said)
        else:
            text = mutate_json(text, rng, said)
    return text


# ---------------------------------------------------------------- running a case


def _cli(*args, timeout: float = 60) -> subprocess.CompletedProcess | str:
    """The command in process; "traceback: ..." or "hang" instead of a result."""
    try:
        return run_in_process(*args, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "hang"
    except Exception as e:                     # noqa: BLE001 (a bug in vtexp: the case)
        tb = traceback.extract_tb(e.__traceback__)
        where = next((f"{Path(f.filename).name}:{f.lineno}" for f in reversed(tb)
                      if "/vtexp/" in f.filename), "?")
        return f"traceback: {type(e).__name__} at {where}: {str(e).splitlines()[0][:200] if str(e) else ''}"


def _judge(case: Case, r) -> bool:
    """Set the outcome for a command that did not succeed; True if it succeeded."""
    if isinstance(r, str):
        case.outcome = "hang" if r == "hang" else "traceback"
        case.detail = r
        return False
    if r.returncode != 0:
        if "Traceback (most recent call last)" in r.stderr:
            case.outcome, case.detail = "traceback", r.stderr.strip().splitlines()[-1][:300]
        elif "vtexp: error:" in r.stderr:
            case.outcome, case.detail = "refused", r.stderr.strip().splitlines()[-1][:300]
        else:
            case.outcome, case.detail = "silent", f"exit {r.returncode} without a message"
        return False
    return True


def _session_runs(case: Case, exp: Path, work: Path) -> None:
    """An experiment that validated runs two trials on the simulator, logged."""
    data = work / "data"
    r = _cli("run", exp, "-p", "01", "--responder", "scripted:random", "--device", "sim",
             "--max-trials", "2", "--data", data, "--quiet")
    if not _judge(case, r):
        return
    logs = list(data.rglob("*_beh.tsv"))
    rows = len(logs[0].read_text(encoding="utf-8").splitlines()) - 1 if logs else 0
    longest = 0.0
    for ev in data.rglob("*_events.tsv"):
        d = pd.read_csv(ev, sep="\t", na_values="n/a")
        if len(d):
            longest = max(longest, float((d["onset"] + d["duration"]).max()))
    if rows < 1:
        case.outcome, case.detail = "silent", f"session accepted but {rows} trials logged"
    elif not longest < MAX_PLAYED_S:            # NaN included
        case.outcome, case.detail = "silent", f"a stimulus playing until {longest} s"
    else:
        case.outcome = "accepted"


def experiment_case(seed: int, work: Path) -> Case:
    rng = random.Random(seed)
    case = Case("experiment", seed)
    base = rng.choice(sorted(EXPERIMENTS.glob("*.yaml")))
    case.mutations.append(base.name)
    exp = work / base.name
    exp.write_text(mutate_text(base.read_text(encoding="utf-8"), "yaml", rng, case.mutations),
                   encoding="utf-8", errors="surrogateescape")
    if _judge(case, _cli("validate", exp)):
        _session_runs(case, exp, work)
    return case


def coding_case(seed: int, work: Path) -> Case:
    rng = random.Random(seed)
    case = Case("coding", seed)
    bases = [p for p in sorted(EXPERIMENTS.glob("*.yaml"))
             if re.search(r"^\s+ref: (\w+)", p.read_text(encoding="utf-8"), re.M)]
    base = rng.choice(bases)
    text = base.read_text(encoding="utf-8")
    ref = re.search(r"^\s+ref: (\w+)", text, re.M).group(1)
    case.mutations.append(f"{base.name}:{ref}")
    coding = (CODINGS / f"{ref}.yaml").read_text(encoding="utf-8")
    (work / f"{ref}.yaml").write_text(mutate_text(coding, "yaml", rng, case.mutations),
                                      encoding="utf-8")
    exp = work / base.name                     # the coding as a file beside the experiment
    exp.write_text(re.sub(r"(^\s+ref: )\w+", rf"\g<1>{ref}.yaml", text, count=1, flags=re.M),
                   encoding="utf-8")
    if _judge(case, _cli("validate", exp)):
        _session_runs(case, exp, work)
    return case


def photograph() -> Path:
    """A photograph no one here took or drew: matplotlib's sample of Grace Hopper."""
    import matplotlib
    return Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"


def image_case(seed: int, work: Path) -> Case:
    rng = random.Random(seed)
    case = Case("image", seed)
    src = photograph()
    if rng.random() < 0.5:                     # the same photograph as a PNG
        from vtexp._cv2 import cv2
        c = cv2()
        png = work / "photo.png"
        c.imwrite(str(png), c.imread(str(src)))
        src = png
    data = src.read_bytes()
    for _ in range(rng.choice([1, 1, 2, 3])):
        data = mutate_bytes(data, rng, case.mutations)
    img = work / ("image" + src.suffix)
    img.write_bytes(data)
    out = work / "pattern.json"
    # each pipeline on a device its paper's coding drives (snake-corners on the SMA pins
    # too: the pulse-trains coding rests a pin rather than refuse the photograph, issue 20)
    pipeline, device = rng.choice([("edge-trace", "vest_6x8"), ("edge-trace", "pad_20x20"),
                                   ("height-contours", "pad_20x20"),
                                   ("snake-corners", "sma_5x5")])
    case.mutations.append(f"{pipeline}:{device}")
    # The pipeline's own threshold (--background none): what is damaged here is the file;
    # the photograph is a portrait on a dark ground that figure-ground separation from a
    # still alone refuses as too low in contrast (tests/test_figure.py covers that path).
    r = _cli("encode", img, "--pipeline", pipeline, "--device", device, "--background", "none",
             "--json", out)
    if not _judge(case, r):
        return case
    try:
        doc = json.loads(out.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        case.outcome, case.detail = "silent", f"accepted, but its JSON: {e}"
        return case
    if "schedule" not in doc:
        case.outcome, case.detail = "silent", "accepted, but no schedule written"
    else:
        case.outcome = "accepted"
    return case


STATS_CASES = [
    ("grid_3x4.csv", ["rm-anova", "--dv", "score", "--within", "shape", "soa",
                      "--subject", "participant"]),
    ("seed000_2x2.csv", ["rm-anova", "--dv", "rate", "--within", "timing", "intensity",
                         "--subject", "participant"]),
    ("grid_3x4.csv", ["posthoc", "--dv", "score", "--within", "shape", "soa", "--factor", "shape",
                      "--subject", "participant"]),
    ("grid_3x4.csv", ["friedman", "--dv", "score", "--factor", "soa",
                      "--subject", "participant"]),
    # published data: Freeman, Heathcote, Chalmers & Hockley (2010), from R's afex
    ("fhch2010.csv", ["rm-anova", "--dv", "correct", "--within", "stimulus", "frequency",
                      "--subject", "id"]),
]


def stats_case(seed: int, work: Path) -> Case:
    rng = random.Random(seed)
    case = Case("stats", seed)
    name, args = rng.choice(STATS_CASES)
    case.mutations.append(f"{name}:{args[0]}")
    f = work / name
    f.write_text(mutate_text((DATA / name).read_text(encoding="utf-8"), "csv", rng,
                             case.mutations), encoding="utf-8")
    r = _cli("stats", args[0], f, *args[1:], "--json")
    if not _judge(case, r):
        return case
    try:
        json.loads(r.stdout)
    except ValueError as e:
        case.outcome, case.detail = "silent", f"accepted, but its JSON: {e}"
        return case
    if re.search(r"\b(nan|inf)\b", r.stdout, re.I) and not r.stderr.strip():
        case.outcome, case.detail = "silent", "a NaN or infinite result, nothing said"
    else:
        case.outcome = "accepted"
    return case


def make_dataset(work: Path) -> Path:
    """Two participants of a small study, as vtexp writes them: the dataset folder."""
    from conftest import MINIMAL
    exp = work / "mini.yaml"
    exp.write_text(MINIMAL, encoding="utf-8")
    for p in ("01", "02"):
        r = run_in_process("run", exp, "-p", p, "--responder", "scripted:accuracy=0.7",
                           "--data", work / "data", "--quiet")
        assert r.returncode == 0, r.stderr
    return work / "data" / "mini"


def _numbers(out: Path, dataset: Path) -> dict[str, str]:
    """The analysis's tables (CSV files), the text that the numbers are in, with the
    dataset's and the output's folders written as <DATASET> and <OUT>."""
    return {p.name: p.read_text(encoding="utf-8").replace(str(dataset), "<DATASET>")
            .replace(str(out), "<OUT>") for p in sorted(out.rglob("*.csv"))}


def _said(stderr: str) -> set[str]:
    """The warnings and notes on stderr, their numbers blanked ("2 of these sessions" and
    "1 of these sessions" are the same message)."""
    return {re.sub(r"\d+(\.\d+)?", "#", ln) for ln in stderr.splitlines()
            if re.match(r"vtexp: (warning|note):", ln, re.I)}


def dataset_reference(dataset: Path, work: Path) -> tuple[dict[str, str], set[str]]:
    """The undamaged dataset's analysis: its tables, and what it says on stderr (that its
    sessions are simulated, a singular fit)."""
    out = work / "reference"
    r = run_in_process("analyze", dataset, "--out", out)
    assert r.returncode == 0, r.stderr
    return _numbers(out, dataset), _said(r.stderr)


def dataset_case(seed: int, work: Path, dataset: Path,
                 reference: tuple[dict[str, str], set[str]]) -> Case:
    """A file of a dataset damaged; ``vtexp analyze`` must refuse it, say on stderr what
    it found (a warning or note the undamaged dataset's analysis does not give), or give
    the undamaged dataset's numbers."""
    numbers, said = reference
    rng = random.Random(seed)
    case = Case("dataset", seed)
    copy = work / "mini"
    shutil.copytree(dataset, copy)
    files = sorted(p for p in copy.rglob("*") if p.is_file()
                   and p.suffix in (".tsv", ".json"))
    f = rng.choice(files)
    case.mutations.append(str(f.relative_to(copy)))
    kind = "tsv" if f.suffix == ".tsv" else "json"
    before = f.read_text(encoding="utf-8")
    f.write_text(mutate_text(before, kind, rng, case.mutations), encoding="utf-8",
                 errors="surrogateescape")
    out = work / "out"
    r = _cli("analyze", copy, "--out", out)
    if not _judge(case, r):
        return case
    got = _numbers(out, copy)
    if got == numbers or _said(r.stderr) - said:
        case.outcome = "accepted"
    else:
        changed = [k for k, v in got.items() if numbers.get(k) != v]
        case.outcome = "silent"
        case.detail = f"other numbers ({', '.join(changed[:3]) or 'tables missing'}), nothing said"
    return case


FAMILIES: dict[str, Callable[..., Case]] = {
    "experiment": experiment_case, "coding": coding_case, "image": image_case,
    "stats": stats_case, "dataset": dataset_case,
}


def run_family(family: str, seeds, tmp: Path, on_case=None) -> list[Case]:
    """Every seed's case of ``family``, each in a folder of its own under ``tmp``."""
    cases = []
    extra = ()
    if family == "dataset":
        base = tmp / "base"
        base.mkdir(parents=True, exist_ok=True)
        ds = make_dataset(base)
        extra = (ds, dataset_reference(ds, base))
    for seed in seeds:
        work = tmp / f"{family}-{seed}"
        work.mkdir(parents=True, exist_ok=True)
        case = FAMILIES[family](seed, work, *extra)
        shutil.rmtree(work, ignore_errors=True)
        cases.append(case)
        if on_case is not None:
            on_case(case)
    return cases
