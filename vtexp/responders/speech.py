"""Speech for participants who cannot see the screen: espeak-ng clips, cached, queued.

Every sentence the participant may hear is rendered to a WAV file by the local
text-to-speech engine espeak-ng before the first trial (:meth:`Voice.prerender`),
cached under ``$VTEXP_SPEECH_CACHE`` (default ``~/.cache/vtexp/speech``) in a
folder per experiment and language, named by the SHA-256 of the text, voice,
rate and engine version: a clip is made once and never changes behind a session.

:class:`Speech` plays clips one after another through an audio output (PsychoPy's
``sound``, :class:`PsychopyAudio`) and keeps the list of what it played, with when
(``played``), for the session record and for tests. The masking noise of seed
001's headphones ("to eliminate any acoustical cues") is a clip too, looped while
a stimulus plays.

The fixed sentences (how to answer, confirmations, breaks) come from a phrase book
per language (:data:`PHRASES`: English and German); an experiment may override any
phrase, and must give all of them for a language that has no book.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import wave
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..clock import REAL, Clock
from ..errors import InputError, SessionError

PHRASES: dict[str, dict[str, str]] = {
    "en": {
        "headphones": "Please put on the headphones now, if they are not on yet. Everything "
                      "you need to know will be spoken through them.",
        "masking": "While you feel each stimulus you will hear a rushing noise, so that the "
                   "sound of the device cannot help you.",
        "keys": "Answer with the keys of your keyboard. After each answer you will hear it "
                "repeated. Press Tab to hear a question again.",
        "continue": "Press space to go on.",
        "begin": "Press space to begin.",
        "ready": "Ready. Feel the stimulus now.",
        "practice": "Practice trial. It does not count.",
        "practice_over": "The practice is over. Now the trials that count begin.",
        "choose_digit": "Press {key} for {option}.",
        "choose_letter_key": "Press the key of the letter you felt.",
        "rating": "Press a number from {low} to {high}.",
        "rating_negative": "For a number below zero, press minus first.",
        "rating_point": "{value}: {label}.",
        "number": "Type a number from {minimum} to {maximum}, then press Enter. The arrow "
                  "keys up and down change it too.",
        "replay": "Press space to feel it again. {left} left.",
        "answer_taken": "{answer}. Taken.",
        "too_large": "{maximum} is the largest number.",
        "too_small": "{minimum} is the smallest number.",
        "not_a_key": "That key is not an answer.",
        "no_replays": "No more replays.",
        "paused": "Please wait. The experimenter is checking the device.",
        "resumed": "The session goes on.",
        "break": "Time for a break. {done} of {total} trials are done. Press space when you "
                 "are ready to go on.",
        "finish": "Thank you. The session is over. You can take off the headphones.",
        "minus": "minus",
    },
    "de": {
        "headphones": "Bitte setzen Sie jetzt die Kopfhörer auf, falls sie noch nicht auf "
                      "sind. Alles, was Sie wissen müssen, hören Sie darüber.",
        "masking": "Während Sie einen Reiz fühlen, hören Sie ein Rauschen, damit das Geräusch "
                   "des Geräts nicht hilft.",
        "keys": "Antworten Sie mit den Tasten der Tastatur. Nach jeder Antwort hören Sie sie "
                "noch einmal. Mit der Tabulatortaste hören Sie eine Frage noch einmal.",
        "continue": "Drücken Sie die Leertaste, um weiterzugehen.",
        "begin": "Drücken Sie die Leertaste, um zu beginnen.",
        "ready": "Achtung. Fühlen Sie jetzt den Reiz.",
        "practice": "Übungsdurchgang. Er zählt nicht.",
        "practice_over": "Die Übung ist vorbei. Jetzt beginnen die Durchgänge, die zählen.",
        "choose_digit": "Drücken Sie {key} für {option}.",
        "choose_letter_key": "Drücken Sie die Taste des Buchstabens, den Sie gefühlt haben.",
        "rating": "Drücken Sie eine Zahl von {low} bis {high}.",
        "rating_negative": "Für eine Zahl unter null drücken Sie zuerst Minus.",
        "rating_point": "{value}: {label}.",
        "number": "Tippen Sie eine Zahl von {minimum} bis {maximum} und drücken Sie Enter. "
                  "Die Pfeiltasten auf und ab ändern sie auch.",
        "replay": "Drücken Sie die Leertaste, um es noch einmal zu fühlen. Noch {left}.",
        "answer_taken": "{answer}. Angenommen.",
        "too_large": "{maximum} ist die größte Zahl.",
        "too_small": "{minimum} ist die kleinste Zahl.",
        "not_a_key": "Diese Taste ist keine Antwort.",
        "no_replays": "Keine Wiederholung mehr.",
        "paused": "Bitte warten Sie. Die Versuchsleitung prüft das Gerät.",
        "resumed": "Es geht weiter.",
        "break": "Zeit für eine Pause. {done} von {total} Durchgängen sind geschafft. Drücken "
                 "Sie die Leertaste, wenn Sie weitermachen möchten.",
        "finish": "Vielen Dank. Die Sitzung ist zu Ende. Sie können die Kopfhörer abnehmen.",
        "minus": "minus",
    },
}


def phrase_book(language: str, overrides: dict[str, str] | None = None) -> dict[str, str]:
    """The phrases for ``language`` (its book, or English's base language book for e.g.
    ``en-gb``), with the experiment's ``overrides``; every phrase must exist."""
    base = PHRASES.get(language) or PHRASES.get(language.split("-")[0].split("_")[0]) or {}
    book = {**base, **(overrides or {})}
    missing = [k for k in PHRASES["en"] if k not in book]
    if missing:
        raise InputError(f"vtexp has no phrase book for language {language!r} (it has "
                         f"{', '.join(PHRASES)}); give every phrase under "
                         f"presentation.phrases: missing {', '.join(missing)}",
                         key="presentation.phrases")
    unknown = [k for k in (overrides or {}) if k not in PHRASES["en"]]
    if unknown:
        raise InputError(f"unknown phrase {unknown[0]!r}; phrases: {', '.join(PHRASES['en'])}",
                         key="presentation.phrases")
    return book


def espeak() -> str:
    exe = shutil.which("espeak-ng")
    if exe is None:
        raise SessionError("the audio mode speaks with espeak-ng, which is not installed: "
                           "sudo apt-get install espeak-ng (Debian/Ubuntu), brew install "
                           "espeak-ng (macOS), or see github.com/espeak-ng/espeak-ng")
    return exe


def espeak_version() -> str:
    r = subprocess.run([espeak(), "--version"], capture_output=True, text=True, timeout=30)
    return r.stdout.strip()


def check_language(language: str) -> None:
    """``language`` must be one of espeak-ng's voices (``espeak-ng --voices``)."""
    r = subprocess.run([espeak(), f"--voices={language}"], capture_output=True, text=True,
                       timeout=30)
    names = [ln.split()[1] for ln in r.stdout.splitlines()[1:] if len(ln.split()) > 1]
    if language not in names:
        everything = subprocess.run([espeak(), "--voices"], capture_output=True, text=True,
                                    timeout=30).stdout.splitlines()[1:]
        known = sorted({ln.split()[1] for ln in everything if len(ln.split()) > 1})
        raise InputError(f"espeak-ng has no language {language!r}; it has "
                         f"{', '.join(known[:40])}{', ...' if len(known) > 40 else ''}",
                         key="presentation.language")


def cache_root() -> Path:
    env = os.environ.get("VTEXP_SPEECH_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "vtexp" / "speech"


def wav_duration_s(path: Path) -> float:
    with wave.open(str(path), "rb") as w:
        return w.getnframes() / float(w.getframerate())


@dataclass
class Voice:
    """Renders sentences with espeak-ng into a cache folder per experiment and language."""

    experiment: str
    language: str = "en"
    rate_wpm: int = 150                    # a little slower than espeak's 175
    folder: Path = field(init=False)
    version: str = field(init=False)

    def __post_init__(self):
        check_language(self.language)
        self.version = espeak_version()
        self.folder = cache_root() / self.experiment / self.language
        self.folder.mkdir(parents=True, exist_ok=True)

    def path_of(self, text: str) -> Path:
        key = hashlib.sha256(f"{self.version}\n{self.language}\n{self.rate_wpm}\n{text}"
                             .encode("utf-8")).hexdigest()[:24]
        return self.folder / f"{key}.wav"

    def clip(self, text: str) -> Path:
        """The clip of ``text``, rendered now if the cache lacks it."""
        path = self.path_of(text)
        if not path.is_file():
            tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.wav")
            # The text goes in on standard input: one starting with '-' is no option.
            r = subprocess.run([espeak(), "-v", self.language, "-s", str(self.rate_wpm),
                                "-w", str(tmp), "--stdin"], input=text, capture_output=True,
                               text=True, timeout=60)
            if r.returncode != 0 or not tmp.is_file():
                raise SessionError(f"espeak-ng could not speak {text[:60]!r}: "
                                   f"{r.stderr.strip() or r.returncode}")
            os.replace(tmp, path)           # a clip is whole or absent
        return path

    def prerender(self, texts) -> int:
        """Render every clip the session may need, espeak-ng running on every core;
        return how many were new."""
        from concurrent.futures import ThreadPoolExecutor

        todo = [t for t in dict.fromkeys(t for t in texts if t and t.strip())
                if not self.path_of(t).is_file()]
        if todo:
            with ThreadPoolExecutor(max_workers=min(len(todo), os.cpu_count() or 1)) as pool:
                list(pool.map(self.clip, todo))     # the first error, if any, is raised
        return len(todo)


def masking_noise(folder: Path, seconds: float = 4.0, rate: int = 22050) -> Path:
    """Pink-ish noise at a moderate level, looped during each stimulus (seed 001's
    headphones "to eliminate any acoustical cues")."""
    path = Path(folder) / f"masking-noise-{rate}.wav"
    if path.is_file():
        return path
    rng = np.random.default_rng(1)
    white = rng.standard_normal(int(seconds * rate))
    # 1/f shaping in the frequency domain; the ends cross-faded so that the loop is seamless.
    spec = np.fft.rfft(white)
    f = np.fft.rfftfreq(white.size, 1 / rate)
    spec[1:] /= np.sqrt(f[1:] / f[1])
    pink = np.fft.irfft(spec, white.size)
    pink *= 0.25 / np.max(np.abs(pink))
    data = (pink * 32767).astype("<i2")
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    with wave.open(str(tmp), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(data.tobytes())
    os.replace(tmp, path)
    return path


#: How the experimenter lists the sound outputs (printed in messages: it must work as printed).
LIST_COMMAND = "vtexp device list --audio"


def output_devices(refresh: bool = True) -> list[dict]:
    """The sound outputs PortAudio sees (through ``sounddevice``, as PsychoPy's sound does):
    ``{"index", "name", "hostapi", "channels", "default"}`` each. ``refresh``: look again
    (PortAudio lists the devices once, when it starts: a sound server or headphones
    started later would be missed), unless PsychoPy already plays on a stream."""
    try:
        import sounddevice as sd
    except Exception as e:          # OSError: no libportaudio2
        raise SessionError(f"the audio mode plays sound through PortAudio, which cannot be "
                           f"loaded ({type(e).__name__}: {e}): sudo apt-get install "
                           "libportaudio2 (Debian/Ubuntu), brew install portaudio (macOS)"
                           ) from None
    if refresh and not _psychopy_streams_open():
        sd._terminate()
        sd._initialize()
    default = sd.default.device[1]
    if default is None or (isinstance(default, int) and default < 0):
        try:
            default = sd.query_devices(kind="output")["index"]
        except Exception:           # PortAudio has no default output
            default = -1
    out = []
    for d in sd.query_devices():
        if d["max_output_channels"] > 0:
            out.append({"index": d["index"], "name": d["name"],
                        "hostapi": sd.query_hostapis(d["hostapi"])["name"],
                        "channels": d["max_output_channels"],
                        "default": d["index"] == default})
    return out


def _psychopy_streams_open() -> bool:
    import sys
    backend = sys.modules.get("psychopy.sound.backend_sounddevice")
    return bool(backend is not None and len(backend.streams))


def choose_output(device: str | None, devices: list[dict] | None = None) -> dict:
    """The output the audio mode plays on: ``device`` (its number in the list, its name, or
    a part of its name that only it has, any case), else the default output. A clear
    message, naming what is missing and how to choose, if there is none."""
    devices = output_devices() if devices is None else devices
    how = (f"choose one with --responder window:audio,device=NAME (a part of its name, or "
           f"its number); list them with: {LIST_COMMAND}")
    if not devices:
        raise SessionError("the audio mode has no sound output to play on: PortAudio finds "
                           "no output device (no sound card, headphones or sound server such "
                           "as PulseAudio or PipeWire). Attach headphones or start the sound "
                           f"server, then {how}")
    if device is None:
        chosen = [d for d in devices if d["default"]] or devices[:1]
        return chosen[0]
    names = "; ".join(f"{d['index']}: {d['name']}" for d in devices)
    if device.isdigit():
        hit = [d for d in devices if d["index"] == int(device)]
    else:
        hit = [d for d in devices if d["name"].lower() == device.lower()] or \
              [d for d in devices if device.lower() in d["name"].lower()]
    if len(hit) == 1:
        return hit[0]
    if not hit:
        raise InputError(f"no sound output {device!r} for the audio mode; the outputs are "
                         f"{names} ({how})", key="--responder")
    raise InputError(f"{len(hit)} sound outputs match {device!r}: "
                     + "; ".join(f"{d['index']}: {d['name']}" for d in hit)
                     + "; give more of the name, or the number", key="--responder")


#: Frames per block of the output's stream (PsychoPy's default is 128: 6 ms at espeak-ng's
#: 22050 Hz). Each block is filled by a Python callback, which needs the GIL and the CPU:
#: on a busy computer (tests/test_audio_sound_server.py run beside other tests) the
#: process went unscheduled for 0.1 s and more, 128- and 512-frame blocks ran dry and the
#: prompts were heard broken up. 2048 frames are 93 ms a block; the output's latency,
#: about two blocks, delays what is said by a fifth of a second, and the masking noise's
#: lead covers it.
BLOCK_FRAMES = 2048


class PsychopyAudio:
    """Plays WAV files through PsychoPy's ``sound`` with the sounddevice backend, on the
    output ``device`` (see :func:`choose_output`; None: the default output). The output is
    chosen when this is made: a computer without one is told before anything is written."""

    def __init__(self, device: str | None = None):
        os.environ.setdefault("PSYCHOPYNOPACKAGES", "1")
        self.output = choose_output(device)
        try:
            from psychopy import prefs
            # Only sounddevice: PTB opens a stream with all of the device's channels (32
            # on ALSA's pulse) and suspends the sound server's sink it plays into.
            prefs.hardware["audioLib"] = ["sounddevice"]
            prefs.hardware["audioDevice"] = self.output["name"]
            from psychopy import sound
            from psychopy.sound import backend_sounddevice
        except Exception as e:          # no audio library, no device
            raise SessionError(f"cannot play sound for the audio mode: {type(e).__name__}: "
                               f"{e}. Is a sound card (or headphones) attached?") from None
        backend_sounddevice.defaultOutput = self.output["index"]   # the stream's device
        self._sound = sound
        self._cache: dict[Path, object] = {}
        self._loop = None

    def _get(self, path: Path, loops: int = 0):
        key = (path, loops)
        snd = self._cache.get(key)
        if snd is None:
            try:
                snd = self._cache[key] = self._sound.Sound(str(path), loops=loops,
                                                           blockSize=BLOCK_FRAMES)
            except Exception as e:
                raise SessionError(f"cannot play {path.name} for the audio mode: "
                                   f"{type(e).__name__}: {e}") from None
        return snd

    def prepare(self, path: Path) -> None:
        """Load the clip (and open the output's stream, the first time)."""
        self._get(path)

    def play(self, path: Path) -> None:
        snd = self._get(path)
        snd.stop()
        snd.play()

    def playing(self, path: Path) -> bool:
        """Whether the output still has samples of the clip to play (False once its last
        block was handed to the output)."""
        snd = self._cache.get((path, 0))
        return bool(snd is not None and snd.isPlaying)

    @property
    def latency_s(self) -> float:
        """At most how long a clip takes from :meth:`play` to the headphones: the output's
        latency as PortAudio reports it, and a block (a clip starts with the next block
        the stream asks for); 0 before the stream opened."""
        from psychopy.sound import backend_sounddevice
        return max((float(getattr(st, "latency", 0.0) or 0.0) + st.blockSize / st.sampleRate
                    for st in backend_sounddevice.streams.values()), default=0.0)

    def stop(self, path: Path) -> None:
        snd = self._cache.get((path, 0))
        if snd is not None:
            snd.stop()

    def loop(self, path: Path) -> None:
        self._loop = self._get(path, loops=-1)
        self._loop.play()

    def stop_loop(self) -> None:
        if self._loop is not None:
            self._loop.stop()
            self._loop = None


#: How long a clip may go on playing past its length (its output ran dry and plays it
#: late) before the next one starts anyway: an output that stopped altogether does not
#: keep the session waiting.
MAX_LATE_S = 2.0


@dataclass
class Played:
    """A clip as it was played: what was said, the file, and when (the speech's clock, s)."""

    text: str
    path: Path
    start: float
    end: float             # when it ended, or was cut off


class Speech:
    """A queue of clips played one after another; :meth:`update` is called every frame.
    A clip lasts its recording's length on ``clock`` (the real one unless given)."""

    def __init__(self, voice: Voice, audio, book: dict[str, str], noise: Path | None = None,
                 clock: Clock = REAL):
        self.clock = clock
        self.voice = voice
        self.audio = audio
        self.book = book
        self.noise = noise
        self.queue: list[tuple[str, Path]] = []
        self.current: tuple[str, Path, float, float] | None = None
        self.played: list[Played] = []
        self.noise_on: list[tuple[float, float]] = []     # (start, stop) of masking noise
        self._noise_since: float | None = None
        self._late = False                  # the clip on now outlasted its length

    def phrase(self, name: str, /, **values) -> str:
        return self.book[name].format(**values)

    def say(self, *texts: str, interrupt: bool = True) -> None:
        """Speak ``texts`` in turn; by default what was being said stops first."""
        if interrupt:
            self.stop()
        for t in texts:
            if t and t.strip():
                self.queue.append((t, self.voice.clip(t)))
        self.update()

    def update(self) -> None:
        now = self.clock.now()
        if self.current is not None and now >= self.current[3]:
            text, path, start, end = self.current
            if self._still_playing() and now < end + MAX_LATE_S:
                self._late = True               # it ends when the output is done with it
            else:
                self.played.append(Played(text, path, start, now if self._late else end))
                self.current, self._late = None, False
        if self.current is None and self.queue:
            text, path = self.queue.pop(0)
            prepare = getattr(self.audio, "prepare", None)
            if prepare is not None:     # loaded first: the start logged is when it plays
                prepare(path)
            start = self.clock.now()
            self.audio.play(path)
            length = getattr(self.audio, "duration", wav_duration_s)(path)
            self.current = (text, path, start, start + length)

    def _still_playing(self) -> bool:
        """The output has not played the clip's last samples yet, though its length has
        passed (its stream ran dry on a busy computer and plays late): the next clip
        waits, so that two are never heard at once."""
        playing = getattr(self.audio, "playing", None)
        return bool(playing is not None and playing(self.current[1]))

    def busy(self) -> bool:
        self.update()
        return self.current is not None or bool(self.queue)

    def stop(self) -> None:
        """Cut off what is being said and forget what was queued."""
        if self.current is not None:
            text, path, start, _ = self.current
            self.audio.stop(path)
            self.played.append(Played(text, path, start, self.clock.now()))
            self.current, self._late = None, False
        self.queue.clear()

    def start_noise(self) -> None:
        if self.noise is not None and self._noise_since is None:
            self.audio.loop(self.noise)
            self._noise_since = self.clock.now()

    def stop_noise(self) -> None:
        if self._noise_since is not None:
            self.audio.stop_loop()
            self.noise_on.append((self._noise_since, self.clock.now()))
            self._noise_since = None
