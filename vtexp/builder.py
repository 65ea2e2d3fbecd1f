"""vtexp inside a PsychoPy experiment: the tactile array as one more device of a script.

The *Tactile stimulus* component of the ``psychopy-vtexp`` plugin
(``plugins/psychopy-vtexp``) writes calls to this module into the script PsychoPy's
Builder compiles; a Coder script can make the same calls. Two objects:

- :class:`TactileArray`, the device, one per experiment, kept in PsychoPy's device
  manager under a name. :meth:`TactileArray.open` opens it and makes the check
  ``vtexp run`` makes before the first trial (:func:`vtexp.devices.check.check_ready`:
  the device is the profile's array, its link answers, every actuator is off);
  :meth:`TactileArray.close` turns every actuator off and closes it (the script calls it
  when the experiment ends or is stopped with Escape; PsychoPy's device manager calls it
  again at exit, after a crash too).
- :class:`TactileStimulus`, one per component: every stimulus it may play is compiled
  and checked against the profile's safety limits by :meth:`TactileStimulus.prepare`
  before the first routine (:func:`vtexp.compile.compile_stimulus`, the path of
  ``vtexp run`` and ``vtexp encode``), so an unsafe stimulus stops the experiment before
  it starts; during a routine it plays on a thread of its own (the frame loop goes on
  drawing and reading keys) through :meth:`~vtexp.devices.base.DeviceBase.play`, which
  checks the schedule again, and reports the device's onsets on PsychoPy's clock.

A stimulus is one of:

- an image file (PNG, JPEG, ...), encoded as it is, as ``vtexp run`` encodes an
  experiment's image files, by ``pipeline`` and coded by ``coding``;
- one of vtexp's stimuli, as ``vtexp encode`` names them: ``GENERATOR:key=value,...``
  (``shape:shape=square``, ``letter:letter=A``, ``surface:surface=ball``);
- a ``.json`` file written by ``vtexp encode --json``: its schedule, played as it is
  once it passes the profile's safety check.

A mistake of the experimenter's (a file that is not there, an unknown device, a
stimulus the profile's limits refuse) ends the script before the first routine with one
line, ``vtexp: error: ...``, naming the component, the conditions file and row, and the
value; nothing is played.
"""

from __future__ import annotations

import atexit
import json
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .errors import InputError, SessionAborted, UnsafeStimulus, VtexpError
from .model import DeviceProfile, PlayReport, Schedule

#: What ``device`` may be: ``sim`` (vtexp's simulated array in real time: nothing is
#: driven, the onsets are the schedule's), ``emulator`` (the firmware's behaviour behind
#: a pseudo-terminal, byte for byte as a real device), ``serial:PORT`` (a device on a
#: serial port, with link settings after commas as for ``vtexp run --device``).
DEVICE_KINDS = ("sim", "emulator", "serial:PORT")

#: The coding each pipeline's paper uses, when ``coding`` is left empty (as ``vtexp
#: encode``).
DEFAULT_CODING = {"height-contours": "contour-modes", "edge-trace": "sequential-trace",
                  "snake-corners": "pulse-trains", "spiral-path": "pulse-trains",
                  "covered-cells": "contour-modes"}


class BuilderError(SystemExit):
    """Ends the script with one line naming what was wrong and where (no traceback):
    Python prints a ``SystemExit``'s text and exits with status 1; the devices are turned
    off and closed on the way out (PsychoPy's device manager, at exit)."""

    def __init__(self, message: str):
        super().__init__(f"vtexp: error: {message}")
        self.message = message


def _fail(message: str) -> BuilderError:
    try:                                  # also into PsychoPy's log file, when there is one
        from psychopy import logging
        logging.error(f"vtexp: {message}")
        logging.flush()
    except Exception:                     # noqa: BLE001 - the message is what matters
        pass
    return BuilderError(message)


def parse_params(text: str, what: str) -> dict[str, Any]:
    """``key=value, key=value`` (values read as YAML: numbers, true/false, lists) into a
    dict; an empty text is no parameters."""
    import yaml

    out: dict[str, Any] = {}
    for item in (text or "").split(","):
        item = item.strip()
        if not item:
            continue
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"expected key=value, got {item!r}", key=what)
        try:
            out[key.strip()] = yaml.safe_load(value.strip())
        except yaml.YAMLError:
            out[key.strip()] = value.strip()
    return out


def _first_error(e) -> str:
    err = e.errors(include_url=False)[0]
    where = ".".join(map(str, err["loc"]))
    return f"{where}: {err['msg']}" if where else err["msg"]


def compile_spec(profile: DeviceProfile, *, stimulus: str, pipeline: str = "",
                 coding: str = "", encoding_params: str = "", coding_params: str = "",
                 folder: Path | None = None) -> Schedule:
    """One stimulus of a component as a Schedule for ``profile``, checked against its
    safety limits (see the module docstring for what ``stimulus`` may be). Raises
    :class:`~vtexp.errors.InputError` naming the value that is wrong, or
    :class:`~vtexp.errors.UnsafeStimulus`."""
    from pydantic import ValidationError

    from .coding import CODINGS
    from .compile import compile_stimulus
    from .encoding import PIPELINES
    from .safety import check_schedule
    from .stimuli import GENERATORS, read_image, render

    text = str(stimulus).strip()
    if not text:
        raise InputError("no stimulus given (an image file, GENERATOR:key=value,... or a "
                         "pattern file from 'vtexp encode --json')", key="stimulus")
    head, sep, rest = text.partition(":")
    path = Path(text) if folder is None or Path(text).is_absolute() else folder / text
    if text.lower().endswith(".json"):
        return _pattern_file(path, profile, check_schedule)
    if sep and head in GENERATORS and not path.exists():
        try:
            params = parse_params(rest, "stimulus")
            GENERATORS[head][1].model_validate(params)
            image = render(head, params, profile.rows, profile.cols)
        except ValidationError as e:
            raise InputError(f"{text!r}: {_first_error(e)}", key="stimulus") from None
        except ValueError as e:
            raise InputError(f"{text!r}: {e}", key="stimulus") from None
    elif sep and not path.exists() and "/" not in head and "\\" not in head and "." not in head:
        raise InputError(f"{text!r}: unknown stimulus generator {head!r}; available: "
                         f"{', '.join(sorted(GENERATORS))} (or an image file)", key="stimulus")
    else:
        image = read_image(path)
    if pipeline not in PIPELINES:
        raise InputError(f"unknown pipeline {pipeline!r}; available: "
                         f"{', '.join(sorted(PIPELINES))}", key="pipeline")
    coding = coding or DEFAULT_CODING.get(pipeline, "")
    if coding not in CODINGS:
        raise InputError(f"unknown coding {coding!r}; available: {', '.join(sorted(CODINGS))}",
                         key="coding")
    enc = parse_params(encoding_params, "encoding parameters")
    cod = parse_params(coding_params, "coding parameters")
    try:
        _, schedule = compile_stimulus(image, profile, pipeline=pipeline, encoding_params=enc,
                                       protocol=coding, coding_params=cod)
    except ValidationError as e:
        which = ("encoding parameters" if e.title == PIPELINES[pipeline][1].__name__
                 else "coding parameters")
        raise InputError(_first_error(e), key=which) from None
    if schedule is None:
        raise InputError(f"{text!r} gives an empty pattern on {profile.name} (no shape "
                         "found in the image)", key="stimulus")
    return schedule


def _pattern_file(path: Path, profile: DeviceProfile, check: Callable) -> Schedule:
    """The schedule of a ``vtexp encode --json`` file, for ``profile``'s array."""
    from pydantic import ValidationError

    if not path.is_file():
        raise InputError("pattern file not found", path=str(path))
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        raise InputError(f"not a pattern file written by 'vtexp encode --json': {e}",
                         path=str(path)) from None
    if not isinstance(data, dict) or "schedule" not in data or "device" not in data:
        raise InputError("not a pattern file written by 'vtexp encode --json' (it has no "
                         "'device' and 'schedule')", path=str(path))
    if data["device"] != profile.name:
        raise InputError(f"written for device profile {data['device']!r}, not "
                         f"{profile.name!r}: encode it again with --device {profile.name}",
                         path=str(path))
    if data["schedule"] is None:
        raise InputError("its pattern is empty (no shape was found): nothing to play",
                         path=str(path))
    try:
        schedule = Schedule.model_validate(data["schedule"])
    except ValidationError as e:
        raise InputError(f"schedule: {_first_error(e)}", path=str(path)) from None
    check(schedule, profile)
    return schedule


def _device_clock_offset_s(now_s: Callable[[], float], device_ms: Callable[[], float]) -> float:
    """PsychoPy's clock minus the device's host clock (s), from the closest of a few
    readings of both (the pair read with the least time between them)."""
    best = None
    for _ in range(5):
        a = now_s()
        d = device_ms() / 1000.0
        b = now_s()
        if best is None or b - a < best[0]:
            best = (b - a, (a + b) / 2 - d)
    return best[1]


class TactileArray:
    """The tactile array of an experiment (see the module docstring).

    ``device``: ``sim``, ``emulator`` or ``serial:PORT`` (:data:`DEVICE_KINDS`);
    ``profile``: a shipped device profile's name or a profile YAML file. Making one
    opens nothing (PsychoPy's device manager makes it); :meth:`open` does.
    """

    def __init__(self, device: str = "sim", profile: str = "", name: str = "tactileArray",
                 **options: Any):
        self.spec = str(device).strip()
        self.profile_name = str(profile).strip()
        self.name = name
        self.options = options
        self.device = None
        self.profile: DeviceProfile | None = None
        self._stimuli: list[TactileStimulus] = []
        self._schedules: dict[tuple, Schedule] = {}

    # PsychoPy's device manager asks these of its devices
    def isSameDevice(self, other: Any) -> bool:
        if isinstance(other, dict):
            return other.get("device") == self.spec
        return isinstance(other, TactileArray) and other.spec == self.spec

    @staticmethod
    def getAvailableDevices() -> list[dict]:
        out = [{"deviceName": "vtexp sim", "device": "sim"},
               {"deviceName": "vtexp emulator", "device": "emulator"}]
        try:
            from serial.tools import list_ports
            out += [{"deviceName": f"vtexp on {p.device}", "device": f"serial:{p.device}"}
                    for p in list_ports.comports()]
        except Exception:                 # noqa: BLE001 - no port listing: none offered
            pass
        return out

    def open(self, say: Callable[[str], None] | None = None, *, device: str | None = None,
             profile: str | None = None) -> TactileArray:
        """Open the device and check it as ``vtexp run`` does before the first trial.
        Opening an open array does nothing (one device, opened once per experiment).

        ``device`` and ``profile``: what the component opening it asks for; components
        sharing a device name must ask for the same array, or the script ends here in
        one line naming both."""
        for asked, mine, what in ((device, self.spec, "device"),
                                  (profile, self.profile_name, "profile")):
            if asked is not None and str(asked).strip() != mine:
                raise _fail(f"{self.name}: two components name this array with different "
                            f"{what}s ({mine!r} and {str(asked).strip()!r}); give each "
                            "array a device name of its own, or the same settings")
        if self.device is not None:
            return self
        from .devices import open_device
        from .devices.check import check_ready

        say = say or _log_info
        where = f"{self.name} (device {self.spec!r}, profile {self.profile_name!r})"
        try:
            if not self.profile_name:
                raise InputError("no device profile given; shipped profiles: "
                                 + ", ".join(_profiles()), key="profile")
            self.profile = DeviceProfile.load(self.profile_name)
            spec = "sim:realtime" if self.spec == "sim" else self.spec
            if spec == "sim:virtual" or spec == "emulator:virtual":
                raise InputError(f"{self.spec!r} keeps a virtual clock, not a person's time; "
                                 "use sim, emulator or serial:PORT", key="device")
            self.device = open_device(spec, self.profile, **self.options)
            if not getattr(self, "_at_exit", False):   # also without the device manager
                atexit.register(self.close)
                self._at_exit = True
            self.device.open()
            check_ready(self.device, self.profile, say=say)
        except VtexpError as e:
            self.close()
            raise _fail(f"{where}: {_message(e)}. Nothing was played.") from None
        say(f"{self.name}: device check passed; no actuator is on")
        return self

    def schedule(self, key: tuple, make: Callable[[], Schedule]) -> Schedule:
        if key not in self._schedules:
            self._schedules[key] = make()
        return self._schedules[key]

    def close(self) -> None:
        """Stop any play, turn every actuator off, close the device. Safe to call again;
        :meth:`open` opens it anew (an experiment run again in the same process)."""
        stimuli, self._stimuli = self._stimuli, []
        for s in stimuli:
            s.stop()
        device, self.device = self.device, None
        if device is not None:
            try:
                device.close()
            except VtexpError as e:           # a device lost: its watchdog turned it off
                _log_error(f"{self.name}: closing the device: {_message(e)}")


def _message(e: BaseException) -> str:
    return getattr(e, "format", lambda: str(e))() if isinstance(e, InputError) else str(e)


def _profiles() -> list[str]:
    from .model import available_profiles
    return available_profiles()


def _log_info(text: str) -> None:
    try:
        from psychopy import logging
        logging.info(f"vtexp: {text}")
    except ImportError:
        pass


def _log_warning(text: str) -> None:
    try:
        from psychopy import logging
        logging.warning(f"vtexp: {text}")
    except ImportError:
        pass


def _log_error(text: str) -> None:
    try:
        from psychopy import logging
        logging.error(f"vtexp: {text}")
    except ImportError:
        pass


class TactileStimulus:
    """One Tactile stimulus component: what it plays in a routine and what it saves.

    PsychoPy's frame code reads and sets ``status``, ``tStart``, ``tStop``,
    ``frameNStart`` and the like on it, as on any component.
    """

    def __init__(self, array: TactileArray, name: str, folder: str | Path | None = None):
        self.array = array
        self.name = name
        self.folder = Path(folder) if folder is not None else Path.cwd()
        self.status = None
        self.tStart = self.tStop = self.tStartRefresh = self.tStopRefresh = None
        self.frameNStart = self.frameNStop = None
        self._schedule: Schedule | None = None
        self._spec: dict[str, str] = {}
        self._clock_now: Callable[[], float] | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._report: PlayReport | None = None
        self._error: BaseException | None = None
        self._offset_s: float | None = None
        array._stimuli.append(self)

    # -- before the first routine ------------------------------------------------------------
    def prepare(self, where: str = "", **spec: Any) -> Schedule:
        """Compile one stimulus ``spec`` (``stimulus``, ``pipeline``, ``coding``,
        ``encoding_params``, ``coding_params``) and check it against the profile; ``where``
        says which conditions file and row it came from, for the message if it fails."""
        if self.array.profile is None:
            raise _fail(f"{self.name}: the device {self.array.name!r} was not opened "
                        "before the stimuli were prepared")
        spec = {k: ("" if v is None else str(v)) for k, v in spec.items()}
        key = tuple(sorted(spec.items())) + (str(self.folder),)
        try:
            return self.array.schedule(key, lambda: compile_spec(
                self.array.profile, folder=self.folder, **spec))
        except UnsafeStimulus as e:
            raise _fail(f"{self._where(where)}stimulus {spec.get('stimulus')!r}: unsafe on "
                        f"{self.array.profile.name}: {e}. Nothing was played.") from None
        except InputError as e:
            raise _fail(f"{self._where(where)}{e.format()}. Nothing was played.") from None

    def prepare_rows(self, conditions: list[tuple[str, list[dict]]], namespace: dict,
                     **exprs: str) -> int:
        """Every stimulus the conditions files ask for, compiled and checked before the
        first routine: ``conditions`` holds each loop's file and rows (nested loops: every
        combination of their rows), ``exprs`` each parameter's Python expression as
        Builder wrote it, evaluated with a row's columns (``namespace``: the script's
        globals). A value that names something no row gives (a variable a code component
        sets) is known only at its routine's start, where it is compiled and checked
        before anything of the trial plays. Returns how many stimuli were compiled."""
        import itertools

        numbered = [[(Path(str(f)).name, i, row or {}) for i, row in enumerate(rows, 1)]
                    for f, rows in conditions]
        n = 0
        for combo in itertools.product(*numbered):
            row: dict[str, Any] = {}
            for _, _, r in combo:
                row.update(r)
            where = ", ".join(f"{f} row {i}" for f, i, _ in combo)
            spec = {}
            for key, expr in exprs.items():
                try:
                    spec[key] = eval(expr, namespace, row)      # noqa: S307 - Builder's code
                except NameError as e:
                    _log_warning(f"{self.name}: {key} = {expr}: {e}; compiled and checked "
                                 "at its routine's start instead")
                    spec = None
                    break
                except Exception as e:                           # noqa: BLE001
                    raise _fail(f"{self._where(where)}{key} = {expr}: "
                                f"{type(e).__name__}: {e}. Nothing was played.") from None
            if spec is not None:
                self.prepare(where, **spec)
                n += 1
        _log_info(f"{self.name}: {n} stimuli compiled and within "
                  f"{self.array.profile.name}'s safety limits")
        return n

    def _where(self, where: str) -> str:
        return f"{self.name}" + (f", {where}" if where else "") + ": "

    # -- each routine --------------------------------------------------------------------------
    def start_routine(self, clock: Any, **spec: Any) -> None:
        """At the start of a routine: this trial's stimulus (prepared before the first
        routine; one whose values could not be known then is compiled and checked now,
        before anything of the trial plays), and PsychoPy's clock the onsets are put on."""
        self._finish_thread()
        self._schedule = self.prepare("", **spec)
        self._spec = {k: ("" if v is None else str(v)) for k, v in spec.items()}
        self._clock_now = (lambda: clock.getTime(format="float")) if clock is not None else None
        self._report = None
        self._error = None
        self._offset_s = None
        self._stop.clear()

    def play(self) -> None:
        """Start playing this routine's stimulus (on a thread: the frame loop goes on)."""
        if self._thread is not None or self._schedule is None:
            return
        dev = self.array.device
        if self._clock_now is not None:
            self._offset_s = _device_clock_offset_s(self._clock_now, dev.clock.now_ms)
        schedule = self._schedule

        def run() -> None:
            try:
                self._report = dev.play(schedule, should_stop=self._stop.is_set)
            except SessionAborted as e:  # stopped: every actuator is off (DeviceBase.play)
                self._report = e.played  # and what the device had played until then
            except BaseException as e:  # noqa: BLE001 - said on the main thread
                self._error = e

        self._thread = threading.Thread(target=run, name=f"vtexp {self.name}", daemon=True)
        self._thread.start()

    @property
    def finished(self) -> bool:
        """The play has ended (played whole, stopped, or failed)."""
        self._raise_error()
        return self._thread is not None and not self._thread.is_alive()

    def stop(self) -> None:
        """Stop the play now, if it is still playing: every actuator off at once."""
        self._stop.set()
        self._finish_thread()

    def _finish_thread(self) -> None:
        t = self._thread
        if t is not None:
            t.join(5.0)
            self._thread = None if not t.is_alive() else t

    def _raise_error(self) -> None:
        e = self._error
        if e is not None:
            self._error = None
            if isinstance(e, VtexpError):
                raise _fail(f"{self.name}: {_message(e)}") from None
            raise e

    # -- what a trial saves ----------------------------------------------------------------
    def data(self) -> dict[str, Any]:
        """This routine's columns for PsychoPy's data file (``NAME.onsets`` etc.)."""
        self.stop()
        self._raise_error()
        n = self.name
        s = self._schedule
        r = self._report
        out: dict[str, Any] = {f"{n}.stimulus": self._spec.get("stimulus", ""),
                               f"{n}.pulses_scheduled": len(s.pulses) if s else 0}
        if r is None:               # stopped before the play started
            out.update({f"{n}.pulses_played": 0, f"{n}.completed": False,
                        f"{n}.onsets": [], f"{n}.actuators": []})
            return out
        base = r.started_at_host_ms
        onsets = ([round((base + p.onset_ms) / 1000.0 + self._offset_s, 6) for p in r.pulses]
                  if base is not None and self._offset_s is not None else [])
        out.update({
            f"{n}.pulses_played": len(r.pulses),
            f"{n}.completed": r.completed,
            # the device-reported onset of every pulse, on PsychoPy's clock (s)
            f"{n}.onsets": onsets,
            f"{n}.actuators": [f"{p.row},{p.col}" for p in r.pulses],
            f"{n}.device_onsets_ms": [round(p.onset_ms, 3) for p in r.pulses],
            f"{n}.clock_error_ms": r.host_clock_error_ms,
        })
        return out
