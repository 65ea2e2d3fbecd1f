"""Child processes forked from a server that has vtexp imported (multiprocessing's
``forkserver``), for the tests that kill a process many times over.

A child is a process of its own, as ``python session_child.py`` is: SIGKILL ends it
where it stands, and what it had written is all that is left. Started from the server,
it skips the half second of importing vtexp, which a test that kills and resumes a
session dozens of times would otherwise spend on every run. Its lines come back
through a pipe, in order, until it ends.
"""

from __future__ import annotations

import multiprocessing
import os
import signal

#: What the server imports once, before it forks any child.
PRELOAD = ["session_child", "vtexp.session", "vtexp.compile", "vtexp.devices.sim",
           "vtexp.responders.scripted", "cv2"]

_context = None


def _ctx():
    global _context
    if _context is None:
        _context = multiprocessing.get_context("forkserver")
        _context.set_forkserver_preload(PRELOAD)
    return _context


def _run(target, args, out) -> None:
    def say(line: str) -> None:
        out.send_bytes(line.encode("utf-8"))
    target(list(args), say)
    out.close()


class Child:
    """``target(args, say)`` in a forked child; ``say(line)`` sends a line back."""

    def __init__(self, target, *args: str, timeout: float = 120.0):
        ctx = _ctx()
        lines, out = ctx.Pipe(duplex=False)
        self.process = ctx.Process(target=_run, args=(target, args, out))
        self.process.start()
        out.close()                 # the child's end: the pipe ends when the child does
        self._lines = lines
        self.pid = self.process.pid
        self.timeout = timeout      # the longest a line (or the end) is waited for

    def __iter__(self):
        """The child's lines as they come, until it ends."""
        while True:
            if not self._lines.poll(self.timeout):
                raise TimeoutError(f"child {self.pid} said nothing for {self.timeout} s")
            try:
                yield self._lines.recv_bytes().decode("utf-8")
            except (EOFError, OSError):
                return

    def poll(self) -> int | None:
        return self.process.exitcode

    def kill(self) -> None:
        os.kill(self.pid, signal.SIGKILL)

    def wait(self) -> int:
        """The exit code (negative: the signal that ended it)."""
        self.process.join(self.timeout)
        if self.process.exitcode is None:
            raise TimeoutError(f"child {self.pid} still running after {self.timeout} s")
        return self.process.exitcode

    def rest(self) -> str:
        """What the child says until it ends, once it has ended."""
        text = "".join(line + "\n" for line in self)
        self.wait()
        return text
