"""The console responder: the participant (or the experimenter for them) answers in the
terminal. For labs without a second screen, and for runs driven by a script through
standard input.

Each question is printed with its numbered options (a choice), its scale with the labels
(a rating) or its range (a number); the answer is typed and confirmed with Enter: the
option's number or its text, the rating, the number. ``r`` feels the stimulus again
where the question allows it; ``q`` aborts the session (every actuator off, completed
trials kept), as does the end of the input. The reaction time runs from the moment the
question is printed (the stimulus has ended) to Enter.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from ..design import Trial
from ..errors import SessionAborted
from .base import Replay, Response


class ConsoleResponder:
    description = "console"
    participant_kind = "person"

    def __init__(self, stdin: TextIO | None = None, stdout: TextIO | None = None):
        self.stdin = stdin or sys.stdin
        self.stdout = stdout or sys.stdout

    # -- screens ---------------------------------------------------------------------------
    def _say(self, text: str = "") -> None:
        print(text, file=self.stdout, flush=True)

    def _line(self, prompt: str) -> str:
        self.stdout.write(prompt)
        self.stdout.flush()
        line = self.stdin.readline()
        if not line:
            raise SessionAborted("the console's input ended")
        line = line.strip()
        if line.lower() in ("q", "quit", "abort"):
            raise SessionAborted("aborted at the console")
        return line

    def instructions(self, text: str) -> None:
        for page in text.split("\n---\n"):
            self._say(page.strip())
            self._line("(Enter to continue) ")

    def stimulus_starts(self, trial: Trial) -> None:
        self._say(f"\nTrial {trial.number}: feel the stimulus...")

    def pause(self, text: str) -> None:
        self._say(text)
        self._line("(Enter to continue) ")

    def finish(self, text: str) -> None:
        self._say(text)

    # -- questions -------------------------------------------------------------------------
    def ask(self, question, trial: Trial, replay: Replay | None) -> Response:
        kind = getattr(question, "kind", "choice")
        options = list(question.options)
        self._say(question.prompt)
        if kind == "choice":
            for i, o in enumerate(options, start=1):
                self._say(f"  {i}. {o}")
        elif kind == "rating":
            self._say("  " + "  ".join(
                f"{v}" + (f" ({question.labels[v]})" if v in question.labels else "")
                for v in question.scale))
        else:
            self._say(f"  a whole number from {question.minimum} to {question.maximum}")
        used, left = 0, (question.replays if replay is not None else 0)
        t0 = time.monotonic()
        while True:
            hint = f", r to feel it again ({left - used} left)" if used < left else ""
            answer = self._line(f"answer{hint}: ")
            if answer.lower() == "r" and used < left:
                replay()
                used += 1
                t0 = time.monotonic()          # the time runs again from the replay's end
                continue
            if kind == "choice" and answer.isdigit() and 1 <= int(answer) <= len(options):
                answer = options[int(answer) - 1]
            if answer in options:
                return Response(answer=answer, rt_s=time.monotonic() - t0, replays=used)
            self._say(f"  '{answer}' is not an answer here; type "
                      + ("an option's number or text" if kind == "choice" else
                         f"one of {options[0]}..{options[-1]}"))


def make_console(arg: str) -> ConsoleResponder:
    return ConsoleResponder()
