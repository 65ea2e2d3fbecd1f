"""``--record DIR``: everything a live run did, to replay it and analyse it later.

The folder is created by the run (an existing folder is never written into) and holds:

``live.json``
    the run: command line, source, pipeline, coding and their parameters, the device
    profile and what the device reported, start and end, status, the run's figures
    (fps, dropped frames, latency percentiles, degradations); rewritten atomically at
    the start and at the end (``status`` ``running`` until then).
``frames.tsv``
    one row per frame processed: its number from the source, capture time, when it
    was processed and how long that took, frames dropped so far, points found, the
    centroid of the points its cycle actuates (array coordinates), cycle length,
    whether its cycle was new, the same as the one playing, or empty.
``programs.jsonl``
    one JSON line per new cycle: the frame, the Pattern and the Schedule (one cycle),
    the cycle length.
``outputs.tsv``
    one row per frame of outputs sent: host time, the device-reported time of the
    change and that time on the host's clock, the frame whose cycle was playing, how
    many outputs changed, the whole state of the array after it (``row,col:level`` or
    ``row,col:volts/Hz/ms``, space-separated), what the safety guard left out, and the
    glass-to-skin latency of the frame it completed (if it did).

Times are milliseconds from the start of the run (on the run's clock: the device's,
``time.monotonic`` on the real one). Rows are
written by a writer thread in batches, one ``write`` and ``fsync`` per file per
batch (at most ``flush_s`` apart), so that the loop never waits for the disk; a crash
loses at most the rows of the last ``flush_s``, and a row cut short is detected by
:func:`load_record` (no final newline) and dropped.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import SessionError
from ..log import TsvLog, write_json_atomic
from ..model import Pattern, PulseTrain, Schedule
from ..safety import Actuator, Drive

FRAME_COLUMNS = ["frame", "t_capture_ms", "t_processed_ms", "process_ms", "encode_ms",
                 "dropped_so_far", "points", "centroid_row", "centroid_col", "cycle_ms",
                 "program", "snake_init", "name"]
OUTPUT_COLUMNS = ["t_host_ms", "t_device_ms", "t_onset_ms", "frame", "changed", "on",
                  "outputs", "degradations", "latency_ms", "latency_frame"]


def format_state(state: dict[Actuator, Drive]) -> str:
    """``row,col:level`` or ``row,col:volts/Hz/ms`` for every actuator on, raster order."""
    parts = []
    for (r, c), d in sorted(state.items()):
        if isinstance(d, PulseTrain):
            parts.append(f"{r},{c}:{d.amplitude_v:g}/{d.frequency_hz:g}/{d.pulse_width_ms:g}")
        else:
            parts.append(f"{r},{c}:{d}")
    return " ".join(parts)


def parse_state(text: str) -> dict[Actuator, Drive]:
    out: dict[Actuator, Drive] = {}
    for part in str(text or "").split():
        where, _, what = part.partition(":")
        r, _, c = where.partition(",")
        if "/" in what:
            a, f, w = (float(x) for x in what.split("/"))
            out[(int(r), int(c))] = PulseTrain(amplitude_v=a, frequency_hz=f, pulse_width_ms=w)
        else:
            out[(int(r), int(c))] = int(what)
    return out


class Recorder:
    """A sink of :class:`~vtexp.live.loop.LiveRun` that writes the record folder."""

    def __init__(self, folder: str | Path, meta: dict[str, Any], *, t0: float,
                 flush_s: float = 0.1):
        self.folder = Path(folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=False)
        except FileExistsError:
            raise SessionError(f"{self.folder} already exists; a live record is never written "
                               "into an existing folder (choose a new --record folder)") from None
        except OSError as e:
            raise SessionError(f"cannot create {self.folder}: {e.strerror or e}") from None
        self.meta = {**meta, "status": "running", "format": "vtexp-live-record/1"}
        self.t0 = t0
        self.flush_s = flush_s
        write_json_atomic(self.folder / "live.json", self.meta)
        self.frames = TsvLog(self.folder / "frames.tsv", FRAME_COLUMNS)
        self.outputs = TsvLog(self.folder / "outputs.tsv", OUTPUT_COLUMNS)
        self._programs = open(self.folder / "programs.jsonl", "x", encoding="utf-8")
        self._queue: queue.Queue = queue.Queue()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True, name="vtexp-live-record")
        self._thread.start()

    def _ms(self, t: float | None) -> float | None:
        return None if t is None else round((t - self.t0) * 1000.0, 3)

    # -- the sink (loop thread: no disk) ----------------------------------------------------
    def __call__(self, kind: str, e: dict) -> None:
        if self._error is not None:
            raise self._error
        if kind == "frame":
            self._queue.put(("frames", {
                "frame": e["frame"], "t_capture_ms": self._ms(e["t_capture"]),
                "t_processed_ms": self._ms(e["t_processed"]),
                "process_ms": round(e["process_ms"], 3), "encode_ms": round(e["encode_ms"], 3),
                "dropped_so_far": e["dropped_so_far"], "points": e["points"],
                "centroid_row": e["centroid_row"], "centroid_col": e["centroid_col"],
                "cycle_ms": e["cycle_ms"], "program": e["program"],
                "snake_init": e["snake_init"], "name": e["name"] or None}))
        elif kind == "program":
            self._queue.put(("programs", e))
        elif kind == "output":
            self._queue.put(("outputs", {
                "t_host_ms": self._ms(e["t_host"]),
                "t_device_ms": None if e["t_device_ms"] is None else round(e["t_device_ms"], 3),
                "t_onset_ms": self._ms(e["t_onset_host"]), "frame": e["frame"],
                "changed": e["changed"], "on": e["on"], "outputs": format_state(e["applied"]),
                "degradations": ";".join(f"{d.kind}={len(d.actuators)}"
                                         for d in e["degradations"]) or None,
                "latency_ms": None if e["latency_ms"] is None else round(e["latency_ms"], 3),
                "latency_frame": e["latency_frame"]}))
        elif kind == "end":
            self.meta["summary"] = e

    # -- the writer thread -------------------------------------------------------------------
    def _run(self) -> None:
        stop = False
        while not stop:
            batch = []
            try:
                batch.append(self._queue.get(timeout=self.flush_s))
            except queue.Empty:
                continue
            time.sleep(self.flush_s / 2)             # gather a batch
            while True:
                try:
                    batch.append(self._queue.get_nowait())
                except queue.Empty:
                    break
            stop = any(item is None for item in batch)
            try:
                self._write([item for item in batch if item is not None])
            except BaseException as e:           # said by the next call of the sink
                self._error = e
                return

    def _write(self, batch: list) -> None:
        frames = [row for kind, row in batch if kind == "frames"]
        outputs = [row for kind, row in batch if kind == "outputs"]
        programs = [row for kind, row in batch if kind == "programs"]
        self.frames.append_many(frames)
        self.outputs.append_many(outputs)
        if programs:
            import os

            text = "".join(json.dumps({
                "frame": p["frame"], "cycle_ms": p["cycle_ms"],
                "pattern": p["pattern"].model_dump(mode="json"),
                "schedule": p["schedule"].model_dump(mode="json")},
                separators=(",", ":")) + "\n" for p in programs)
            self._programs.write(text)
            self._programs.flush()
            os.fsync(self._programs.fileno())

    def close(self, status: str, **extra: Any) -> None:
        """Write what is queued, then ``live.json`` with the status and the summary."""
        self._queue.put(None)
        self._thread.join(timeout=10)
        self.frames.close()
        self.outputs.close()
        self._programs.close()
        self.meta.update(extra)
        self.meta["status"] = status
        write_json_atomic(self.folder / "live.json", self.meta)
        if self._error is not None:
            raise SessionError(f"the live record in {self.folder} could not be written: "
                               f"{self._error}")


@dataclass
class LiveRecord:
    """A record folder read back (:func:`load_record`)."""

    folder: Path
    meta: dict
    frames: Any                     # pandas DataFrame
    outputs: Any                    # pandas DataFrame
    programs: list[dict] = field(default_factory=list)
    cut_rows: int = 0

    def pattern(self, frame: int) -> Pattern:
        for p in self.programs:
            if p["frame"] == frame:
                return Pattern.model_validate(p["pattern"])
        raise KeyError(frame)

    def schedule(self, frame: int) -> Schedule:
        for p in self.programs:
            if p["frame"] == frame:
                return Schedule.model_validate(p["schedule"])
        raise KeyError(frame)

    def states(self, clock: str = "host") -> list[tuple[float, dict[Actuator, Drive]]]:
        """(ms, state of the array) after each frame of outputs: ms from the start on the
        host's clock, or with ``clock="device"`` the device-reported time at which the
        outputs changed (on the device's own clock; rows the device reported no time
        for are left out)."""
        column = {"host": "t_host_ms", "device": "t_device_ms"}[clock]
        out = []
        for t, s in zip(self.outputs[column], self.outputs["outputs"]):
            try:
                t = float(t)
            except (TypeError, ValueError):
                continue
            if t == t:                                  # not NaN
                out.append((t, parse_state(s if isinstance(s, str) else "")))
        return out

    def changes(self, clock: str = "host") -> list[tuple[float, Actuator, Drive | None]]:
        """Every output change, ``(ms, actuator, drive or None for off)`` on that clock
        (:meth:`states`): what the array did, for
        :func:`vtexp.safety.outputs_schedule` to audit."""
        out: list[tuple[float, Actuator, Drive | None]] = []
        prev: dict[Actuator, Drive] = {}
        for t, state in self.states(clock):
            out.extend((t, k, state.get(k)) for k in sorted(prev.keys() | state.keys())
                       if prev.get(k) != state.get(k))
            prev = state
        return out


def load_record(folder: str | Path) -> LiveRecord:
    """Read a record folder; a row cut off mid-write is dropped and counted."""
    import io

    import pandas as pd

    folder = Path(folder)
    meta_path = folder / "live.json"
    if not meta_path.is_file():
        raise SessionError(f"{folder} is not a vtexp live record (no live.json)")
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    cut = 0

    def table(name: str):
        nonlocal cut
        data = (folder / name).read_bytes()
        end = data.rfind(b"\n") + 1
        cut += int(end < len(data))
        return pd.read_csv(io.BytesIO(data[:end]), sep="\t", na_values=["n/a"],
                           keep_default_na=False)

    frames, outputs = table("frames.tsv"), table("outputs.tsv")
    programs = []
    for line in (folder / "programs.jsonl").read_text(encoding="utf-8").splitlines():
        try:
            programs.append(json.loads(line))
        except json.JSONDecodeError:
            cut += 1
    return LiveRecord(folder, meta, frames, outputs, programs, cut)
