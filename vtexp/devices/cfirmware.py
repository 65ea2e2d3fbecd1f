"""The reference firmware in C (``firmware/``): built on demand, run on this computer.

Two ways to run the same core that a lab flashes (docs/firmware.md):

- :class:`AvrSimulator`: the ATmega2560 build, the very ``.elf``, in simavr through
  the ``vtexp-simavr`` harness: its UART on a pseudo-terminal of its own, simulated
  time paced to the wall clock, and a cycle-stamped trace of what the chip drove
  (``vtexp.devices.fwtrace`` reads it). With ``lockstep=True`` the host keeps time by
  the chip instead (:class:`ChipClock`, a :class:`~vtexp.clock.Clock`): the chip runs
  as fast as the computer goes, never further ahead of the host than a few ms, and
  heartbeats, timeouts and pauses between trials are the chip's time;
- :class:`HostFirmware`: the core compiled for this computer behind a
  pseudo-terminal, with the host's clock and a record of the outputs: the C
  firmware without the chip, fast to start.

Either is ``serial:PORT`` to vtexp, like the Python emulator. :func:`build` runs
``make`` in a cache folder (``$VTEXP_FIRMWARE_BUILD``, else
``~/.cache/vtexp/firmware/<hash of the sources>``), once per version of the sources,
and says what to install when a tool is missing.
"""

from __future__ import annotations

import hashlib
import mmap
import os
import shutil
import signal
import struct
import subprocess
import tempfile
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import Literal

from .. import __version__
from ..errors import DeviceError, InputError
from ..model import DeviceProfile
from ..resources import firmware_dir
from .firmware import FirmwareConfig

Kind = Literal["avr", "host"]
PROFILES = ("pad_20x20", "vest_6x8", "sma_5x5")
# What each part of the build needs (Debian packages); `make system-packages` installs them.
NEEDS = {"avr-gcc": "gcc-avr avr-libc binutils-avr",
         "pkg-config": "pkg-config",
         "simavr": "libsimavr-dev libelf-dev",
         "cc": "gcc"}


def _source_hash(src: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(p for p in src.rglob("*") if p.is_file() and "build" not in p.parts):
        h.update(str(f.relative_to(src)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def build_dir() -> Path:
    """Where the firmware of these sources is (or will be) built."""
    env = os.environ.get("VTEXP_FIRMWARE_BUILD")
    if env:
        return Path(env)
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "vtexp" / "firmware" / _source_hash(firmware_dir())


def _missing_tools(targets: tuple[str, ...]) -> list[str]:
    need = []
    if any(t.startswith("avr") for t in targets):
        need.append("avr-gcc")
    if "sim" in targets:
        need += ["pkg-config", "simavr"]
    if "host" in targets or "sim" in targets:
        need.append("cc")
    missing = []
    for tool in need:
        if tool == "simavr":
            ok = subprocess.run(["pkg-config", "--exists", "simavr"],
                                capture_output=True).returncode == 0 if shutil.which(
                "pkg-config") else False
        else:
            ok = shutil.which(tool) is not None
        if not ok:
            missing.append(NEEDS[tool])
    return missing


def build(*targets: str) -> Path:
    """``make`` the firmware targets (``avr-all``, ``host``, ``sim``) into :func:`build_dir`.

    Returns the build folder. Raises :class:`~vtexp.errors.DeviceError` naming the
    Debian packages to install when a tool is missing, or with the compiler's message
    when the build fails.
    """
    try:
        import fcntl
    except ImportError:                 # Windows
        raise DeviceError("the reference firmware is built and run here with make, flock and "
                          "pseudo-terminals, which this system does not have (Linux and macOS "
                          "do): build and flash it there ('vtexp firmware flash'), then use "
                          "the board here on serial:PORT (e.g. serial:COM3)") from None
    targets = targets or ("avr-all", "host", "sim")
    missing = _missing_tools(targets)
    if missing:
        raise DeviceError("building the reference firmware needs: " + " ".join(missing)
                          + ". Install them with 'make system-packages' (as root) or "
                            "'sudo apt-get install " + " ".join(missing) + "'.")
    out = build_dir()
    out.mkdir(parents=True, exist_ok=True)
    with open(out / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)      # two test processes, one build
        r = subprocess.run(["make", "-s", "-C", str(firmware_dir()), f"O={out}",
                            f"VERSION={__version__}", *targets],
                           capture_output=True, text=True)
    if r.returncode != 0:
        raise DeviceError(f"building the reference firmware failed:\n{r.stderr.strip()}")
    return out


def elf_path(profile: str) -> Path:
    """The ATmega2560 build of ``profile`` (``vectors``: the vector runner's)."""
    out = build("avr-all")
    if profile == "vectors":
        return out / "avr" / "vectors" / "vtexp-fw-vectors.elf"
    return out / "avr" / profile / "vtexp-fw.elf"


def symbols(elf: Path) -> dict[str, int]:
    """The data addresses of the firmware's symbols, by name (for the harness's stack and
    peeks)."""
    r = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True)
    return {parts[2]: int(parts[0], 16) & 0xFFFF
            for parts in (line.split() for line in r.stdout.splitlines()) if len(parts) == 3}


def config_for(profile: DeviceProfile) -> FirmwareConfig:
    """What the C firmware built for ``profile`` reports in HELLO_REPLY (the
    microcontroller build's capacities; ``firmware/ports/avr/vt_profile.h``)."""
    levels = profile.drive.kind == "levels"
    return FirmwareConfig.for_profile(
        profile, max_pulses=256 if levels else 192, max_payload=512 if levels else 256,
        firmware=f"vtexp-fw {__version__} avr {profile.name}",
        device_id=f"atmega2560 {profile.name}")


class _Process:
    """A firmware process serving a pty: started, talked to on stdin, stopped."""

    name = "firmware"

    def __init__(self, argv: list[str], trace: Path | None):
        self.argv = argv
        self.trace_path = trace
        self.proc: subprocess.Popen | None = None
        self.port = ""
        self._lock = threading.Lock()
        self.stderr = ""

    def start(self, timeout_s: float = 10.0) -> str:
        self.proc = subprocess.Popen(self.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, bufsize=1)
        timer = threading.Timer(timeout_s, self._kill)
        timer.start()
        try:
            for line in self.proc.stdout:
                if line.startswith("port "):
                    self.port = line.split(None, 1)[1].strip()
                    return self.port
        finally:
            timer.cancel()
        err = self.proc.stderr.read() if self.proc.stderr else ""
        raise DeviceError(f"{self.name} did not start: {err.strip() or 'no port printed'}")

    def _kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()

    def command(self, line: str) -> str:
        """Send a command (mute, unmute, unplug, replug, reset, faults D C I) and wait for
        it to be done; ``replug`` returns the new port."""
        assert self.proc is not None and self.proc.stdin is not None
        with self._lock:
            self.proc.stdin.write(line + "\n")
            self.proc.stdin.flush()
            for out in self.proc.stdout:
                if out.startswith("port "):
                    self.port = out.split(None, 1)[1].strip()
                elif out.startswith("ok "):
                    return self.port
        raise DeviceError(f"{self.name} stopped while executing {line!r}")

    def stop(self, timeout_s: float = 5.0) -> None:
        """SIGTERM (the trace is flushed and closed), SIGKILL if it does not end in time."""
        p = self.proc
        if p is None:
            return
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout_s)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.stderr = p.stderr.read() if p.stderr else ""
        for f in (p.stdin, p.stdout, p.stderr):
            if f is not None:
                f.close()
        self.proc = None

    def __enter__(self):
        if self.proc is None:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class ChipClock:
    """The simulated chip's clock, in lockstep with ``vtexp-simavr --lockstep FILE``.

    ``FILE`` holds the chip's cycle count and how far the host lets it run; every
    reading of this clock lets the chip run ``lead_s`` further, so the chip goes as fast
    as the computer allows while the host is looking, and stands still while it is not
    (a host that computes takes no time on the chip's clock). Its time is the chip's:
    seconds since it was powered on. It is a real clock in every other way (threads
    may wait on it): :meth:`sleep` and :meth:`wait_for` look at the chip every fraction
    of a millisecond; a chip that stops running for ``stall_s`` of real time raises
    :class:`~vtexp.errors.DeviceError` instead of waiting for ever.
    """

    virtual = False

    def __init__(self, path: str | Path, *, hz: float = 16e6, lead_s: float = 0.02,
                 stall_s: float = 10.0):
        self.path = Path(path)
        self.hz = hz
        self.lead = int(lead_s * hz)
        self.stall_s = stall_s
        try:
            with open(self.path, "r+b") as f:
                self._map = mmap.mmap(f.fileno(), 16)
        except (OSError, ValueError) as e:
            raise DeviceError(f"cannot share the simulated chip's clock through {self.path}: "
                              f"{e}; is vtexp-simavr running with --lockstep?") from None
        self._wall0 = time.time()
        self._seen = (0, time.monotonic())

    def _cycles(self) -> int:
        cycle, allow = struct.unpack_from("<QQ", self._map, 0)
        if cycle + self.lead > allow:
            struct.pack_into("<Q", self._map, 8, cycle + self.lead)
        return cycle

    def now(self) -> float:
        return self._cycles() / self.hz

    def now_ms(self) -> float:
        return self.now() * 1000.0

    def wall(self) -> float:
        return self._wall0 + self.now()

    def _check_running(self, cycles: int) -> None:
        last, since = self._seen
        real = time.monotonic()
        if cycles != last:
            self._seen = (cycles, real)
        elif real - since > self.stall_s:
            raise DeviceError(f"the simulated chip has not run for {self.stall_s:g} s (its "
                              "simulator stopped?)")

    def sleep(self, seconds: float) -> None:
        self.sleep_until(self.now() + seconds)

    def sleep_until(self, t: float) -> None:
        while (c := self._cycles()) < t * self.hz:
            self._check_running(c)
            time.sleep(0.0002)

    def wait_for(self, cond: threading.Condition, predicate: Callable[[], object],
                 timeout: float | None) -> bool:
        end = None if timeout is None else (self.now() + timeout) * self.hz
        with cond:
            while not predicate():
                c = self._cycles()
                if end is not None and c >= end:
                    return bool(predicate())
                self._check_running(c)
                cond.wait(0.0003)
            return True

    def __repr__(self) -> str:
        return f"ChipClock({self.path})"


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


class AvrSimulator(_Process):
    """The ATmega2560 firmware for ``profile`` in simavr, on a pty (see module docstring).

    Parameters
    ----------
    profile:
        Which build (``pad_20x20``, ``vest_6x8``, ``sma_5x5``).
    trace:
        Where the harness writes its trace (if None, a temporary file, removed when this
        object is collected or at exit; ``trace_path``).
    faults:
        ``(drop, corrupt, insert)`` probabilities per byte, both directions.
    seed:
        Of the fault generator.
    lockstep:
        The host keeps time by the chip (:attr:`clock`, a :class:`ChipClock`) instead of
        the chip being paced to the wall clock.
    """

    name = "the ATmega2560 in simavr"

    #: firmware variables read at the end of a run (``Trace.peeks``; see :meth:`peeked`)
    WATCH = {"vt_uart_overruns": 2, "vt_late_ticks": 2}

    def __init__(self, profile: str | None, *, trace: Path | None = None,
                 faults: tuple[float, float, float] = (0.0, 0.0, 0.0), seed: int = 0,
                 elf: Path | None = None, lockstep: bool = False):
        if elf is None and profile not in PROFILES:
            raise InputError(f"unknown firmware profile {profile!r}; built: "
                             f"{', '.join(PROFILES)}", key="--profile")
        out = build("avr-all", "sim")
        self.elf = elf or out / "avr" / str(profile) / "vtexp-fw.elf"
        self.profile = profile
        if trace is None:
            fd, name = tempfile.mkstemp(prefix=f"vtexp-simavr-{profile or 'elf'}-",
                                        suffix=".jsonl")
            os.close(fd)
            trace = Path(name)
            # a trace of our own making goes when this object does (or at exit): it is
            # read after stop(), so not removed there
            weakref.finalize(self, _unlink, name)
        argv = [str(out / "sim" / "vtexp-simavr"), str(self.elf), "--trace", str(trace),
                "--drop", str(faults[0]), "--corrupt", str(faults[1]), "--insert",
                str(faults[2]), "--seed", str(seed)]
        self._watch: dict[int, tuple[str, int]] = {}
        try:
            table = symbols(self.elf)
        except (OSError, subprocess.CalledProcessError):
            table = {}
        if "__bss_end" in table:
            argv += ["--stack-from", hex(table["__bss_end"])]
        for name, size in self.WATCH.items():
            addr = table.get(name)
            if addr is None:
                continue                      # not in this build (a port's own counter)
            self._watch[addr] = (name, size)
            argv += ["--peek", f"{addr:#x}:{size}"]
        self.lockstep_path: Path | None = None
        self._clock: ChipClock | None = None
        if lockstep:
            fd, name = tempfile.mkstemp(prefix="vtexp-simavr-clock-")
            os.close(fd)
            self.lockstep_path = Path(name)
            argv += ["--lockstep", name]
        super().__init__(argv, trace)

    def stop(self, timeout_s: float = 5.0) -> None:
        super().stop(timeout_s)
        if self.lockstep_path is not None:
            self.lockstep_path.unlink(missing_ok=True)

    @property
    def clock(self) -> ChipClock:
        """The chip's clock, for the host (with ``lockstep``)."""
        if self.lockstep_path is None:
            raise DeviceError("the simulated chip is paced to the wall clock; start it with "
                              "lockstep=True to keep time by it")
        if self._clock is None:
            self._clock = ChipClock(self.lockstep_path)
        return self._clock

    def peeked(self, trace) -> dict[str, int]:
        """The watched firmware variables at the end of the run (little-endian), e.g.
        ``vt_uart_overruns``: bytes the UART receive ring had to drop; ``vt_late_ticks``
        (pulse trains): ticks that came while the one before was still preparing, whose
        edges went out a tick late."""
        return {name: int.from_bytes(trace.peeks[a][:size], "little")
                for a, (name, size) in self._watch.items() if a in trace.peeks}


class HostFirmware(_Process):
    """The C core on this computer behind a pty, configured as ``profile``'s device."""

    name = "the host build of the firmware"

    def __init__(self, profile: DeviceProfile, *, trace: Path | None = None,
                 faults: tuple[float, float, float] = (0.0, 0.0, 0.0), seed: int = 0,
                 **overrides):
        out = build("host")
        cfg = config_for(profile)
        over = {k: v for k, v in overrides.items() if k in {f.name for f in fields(cfg)}}
        cfg = FirmwareConfig(**{**cfg.__dict__, "firmware": f"vtexp-fw {__version__} host "
                                f"{profile.name}", "device_id": f"host {profile.name}",
                                **over})
        self.config = cfg
        argv = [str(out / "host" / "vtexp-fw-host")] + [str(getattr(cfg, k)) for k in (
            "rows", "cols", "actuator", "drive", "max_level", "max_amplitude_mv",
            "max_frequency_chz", "max_width_us", "max_pulses", "max_payload",
            "min_watchdog_ms", "max_watchdog_ms", "firmware", "device_id")]
        if trace is not None:
            argv += ["--trace", str(trace)]
        argv += ["--drop", str(faults[0]), "--corrupt", str(faults[1]), "--insert",
                 str(faults[2]), "--seed", str(seed)]
        super().__init__(argv, trace)


__all__ = ["AvrSimulator", "HostFirmware", "PROFILES", "build", "build_dir", "config_for",
           "elf_path"]
