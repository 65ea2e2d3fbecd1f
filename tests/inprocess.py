"""Run ``vtexp`` inside the test process, as if it were a fresh ``python -m vtexp``.

Starting an interpreter costs about a second before the command does anything; most
tests of the command line test what the command does, not the process. ``run_in_process``
calls ``vtexp.cli.main(argv)`` with everything a child process would have of its own
set up as a child would have it, and put back afterwards:

- the three standard file descriptors: 0 reads the given text (or nothing; never a
  terminal), 1 and 2 go to temporary files, so what is written by Python, by C code,
  and by processes the command starts is all captured, in order; ``sys.stdin``,
  ``sys.stdout`` and ``sys.stderr`` are new streams on those descriptors, buffered as
  a child's are when its output is a pipe (stdout in blocks, stderr by line);
- ``sys.argv`` (``[.../vtexp/__main__.py, *args]``, as ``python -m vtexp`` sets it),
  ``os.environ``, the working directory;
- every signal handler (``main`` turns SIGTERM into KeyboardInterrupt);
- the warnings machinery: a fresh interpreter's filters (plus ``-W`` and
  ``PYTHONWARNINGS``), warnings printed on stderr rather than recorded by pytest, and
  none remembered as already shown;
- logging: the root logger as a fresh interpreter has it (no handler, so records of
  WARNING and above reach stderr); handlers that libraries imported earlier set up on
  stdout or stderr write to the command's; every logger's level and handlers put back;
- the garbage collector: the test process's own objects are frozen (``gc.freeze``),
  so a full collection walks only what the command made, as in a new interpreter;
- the exit: ``SystemExit`` and ``main``'s return value become the return code.

Non-daemon threads the command leaves running are waited for, as at an interpreter's
exit, and fail the test if they do not end; daemon threads go on (a process would end
them). An unexpected exception is raised in the test with its traceback, the command's
output attached as a note. What stays from one call to the next is what any
long-lived process keeps: imported modules and their caches, functions registered
with ``atexit`` (run when the test process ends).
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import io
import locale
import logging
import os
import signal
import subprocess
import sys
import tempfile
import threading
import warnings
from collections.abc import Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAIN = ROOT / "vtexp" / "__main__.py"

_LIBC = ctypes.CDLL(None)


def run_in_process(*args, cwd: Path | str | None = None, timeout: float = 120,
                   input: str | bytes | None = None, stdin=None,
                   env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess:
    """``vtexp ARGS`` in this process; the result as ``subprocess.run(..., text=True,
    capture_output=True)`` returns it for ``python -m vtexp ARGS``.

    ``input`` is the text on standard input; ``stdin`` instead a file object or
    descriptor to read it from (e.g. another process's pipe); neither: empty, not a
    terminal. ``env`` replaces ``os.environ`` for the call (default: ``os.environ`` with
    ``PYTHONPATH`` set to this checkout, for processes the command starts). After
    ``timeout`` seconds the command gets SIGINT and ``subprocess.TimeoutExpired`` is
    raised.
    """
    from vtexp.cli import main

    argv = [os.fspath(a) for a in args]
    cmd = [sys.executable, "-m", "vtexp", *argv]
    if env is None:
        env = dict(os.environ, PYTHONPATH=str(ROOT))
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err, \
            _stdin_file(input, stdin) as in_fd:
        timed_out = threading.Event()
        with _as_a_child(in_fd, out.fileno(), err.fileno(), [str(MAIN), *argv], env,
                         cwd or ROOT), _interrupt_after(timeout, timed_out):
            before = set(threading.enumerate())
            code, raised = None, None
            try:
                code = _exit_status(main, argv)
                _wait_for_threads(before, timeout)
            except BaseException as e:     # a bug: raised in the test, with the output
                raised = e
        stdout, stderr = _text(out), _text(err)
    if timed_out.is_set():
        raise subprocess.TimeoutExpired(cmd, timeout, output=stdout, stderr=stderr)
    if raised is not None:
        raised.add_note(f"vtexp {' '.join(argv)}\n--- its stdout ---\n{stdout}"
                        f"--- its stderr ---\n{stderr}")
        raise raised
    return subprocess.CompletedProcess(cmd, code, stdout, stderr)


def _exit_status(main, argv: list[str]) -> int:
    """What ``sys.exit(main(argv))`` would leave as the process's exit status."""
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    if code is None:
        return 0
    if isinstance(code, int):
        return code & 0xFF
    print(code, file=sys.stderr)        # sys.exit("message"), as the interpreter does
    return 1


@contextlib.contextmanager
def _stdin_file(text, stream):
    """A descriptor for standard input: ``stream``'s, or a file holding ``text``."""
    if stream is not None:
        yield stream if isinstance(stream, int) else stream.fileno()
        return
    with tempfile.TemporaryFile() as f:
        if text:
            f.write(text.encode(_encoding()) if isinstance(text, str) else text)
            f.seek(0)
        yield f.fileno()


@contextlib.contextmanager
def _as_a_child(in_fd: int, out_fd: int, err_fd: int, argv: list[str],
                env: Mapping[str, str], cwd) -> None:
    saved_streams = sys.stdin, sys.stdout, sys.stderr
    for s in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        _flush(s)
    _LIBC.fflush(None)
    saved_fds = {fd: os.dup(fd) for fd in (0, 1, 2)}
    saved_argv, saved_env, saved_cwd = sys.argv, dict(os.environ), os.getcwd()
    saved_signals = _signal_handlers()
    try:
        for fd, to in ((0, in_fd), (1, out_fd), (2, err_fd)):
            os.dup2(to, fd)
        enc = _encoding()
        sys.stdin = io.TextIOWrapper(open(0, "rb", closefd=False), encoding=enc)
        sys.stdout = io.TextIOWrapper(open(1, "wb", closefd=False), encoding=enc)
        sys.stderr = io.TextIOWrapper(open(2, "wb", closefd=False), encoding=enc,
                                      errors="backslashreplace", line_buffering=True)
        sys.argv = argv
        os.environ.clear()
        os.environ.update(env)
        os.chdir(cwd)
        with _fresh_warnings(), _fresh_logging(saved_streams[1:]), _own_heap():
            yield
    finally:
        # what the interpreter flushes at exit; the streams stay usable afterwards (a
        # thread still holding one writes wherever descriptors 1 and 2 go by then)
        for s in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
            _flush(s)
        _LIBC.fflush(None)
        sys.stdin, sys.stdout, sys.stderr = saved_streams
        for fd, saved in saved_fds.items():
            os.dup2(saved, fd)
            os.close(saved)
        os.chdir(saved_cwd)
        os.environ.clear()
        os.environ.update(saved_env)
        sys.argv = saved_argv
        for signum, handler in saved_signals.items():
            if signal.getsignal(signum) is not handler:
                signal.signal(signum, handler)


def _flush(stream) -> None:
    with contextlib.suppress(Exception):
        stream.flush()


def _signal_handlers() -> dict[int, object]:
    handlers = {}
    for signum in signal.valid_signals():
        with contextlib.suppress(OSError, ValueError):
            h = signal.getsignal(signum)
            if h is not None:               # None: set outside Python, not ours to touch
                handlers[signum] = h
    return handlers


#: A fresh interpreter's warning filters (a release build, no -W): CPython's defaults.
_DEFAULT_FILTERS = [
    ("default", None, DeprecationWarning, "__main__", 0),
    ("ignore", None, DeprecationWarning, None, 0),
    ("ignore", None, PendingDeprecationWarning, None, 0),
    ("ignore", None, ImportWarning, None, 0),
    ("ignore", None, ResourceWarning, None, 0),
]


def _show_on_stderr(msg) -> None:
    """``warnings._showwarnmsg_impl`` as CPython has it (pytest records warnings instead)."""
    file = msg.file if msg.file is not None else sys.stderr
    if file is None:
        return
    with contextlib.suppress(OSError):
        file.write(warnings._formatwarnmsg(msg))


@contextlib.contextmanager
def _fresh_warnings():
    once = dict(warnings.onceregistry)
    with warnings.catch_warnings():         # puts filters and showwarning back afterwards
        warnings.filters[:] = _DEFAULT_FILTERS
        warnings._processoptions(sys.warnoptions)   # -W and PYTHONWARNINGS, first
        warnings._filters_mutated()         # "shown once" per location: forgotten
        warnings.showwarning = warnings._showwarning_orig
        warnings._showwarnmsg_impl = _show_on_stderr
        warnings.onceregistry.clear()
        try:
            yield
        finally:
            warnings.onceregistry.clear()
            warnings.onceregistry.update(once)


@contextlib.contextmanager
def _fresh_logging(outer_streams):
    """The root logger as a new interpreter has it; handlers that libraries imported
    earlier set up on this process's stdout or stderr write to the command's meanwhile
    (imported in the command's own process, they would have)."""
    root = logging.getLogger()
    manager = root.manager
    loggers = [root, *(lg for lg in manager.loggerDict.values()
                       if isinstance(lg, logging.Logger))]
    saved = [(lg, lg.level, lg.handlers[:], lg.propagate, lg.disabled) for lg in loggers]
    saved_disable = manager.disable
    root.handlers[:] = []                   # no handler: logging.lastResort, on stderr
    root.setLevel(logging.WARNING)
    logging.disable(logging.NOTSET)
    stdout = {id(s) for s in (outer_streams[0], sys.__stdout__)}
    stderr = {id(s) for s in (outer_streams[1], sys.__stderr__)}
    moved = []
    for lg in loggers[1:]:
        for h in lg.handlers:
            if isinstance(h, logging.StreamHandler) and not isinstance(h, logging.FileHandler):
                to = sys.stdout if id(h.stream) in stdout else \
                    sys.stderr if id(h.stream) in stderr else None
                if to is not None:
                    moved.append((h, h.setStream(to)))
    try:
        yield
    finally:
        for h, stream in moved:
            h.setStream(stream)
        for lg, level, handlers, propagate, disabled in saved:
            lg.setLevel(level)
            lg.handlers[:] = handlers
            lg.propagate, lg.disabled = propagate, disabled
        logging.disable(saved_disable)


#: Set by tests/conftest.py once it has frozen what collection made, for the whole run:
#: then every object older than a call stays frozen after it. Asking the collector
#: instead (``gc.get_freeze_count``) walks every frozen object, 50 ms at 3 million: a
#: test process holds millions by its end, and the suite makes about 350 calls.
RUN_FROZEN = False


@contextlib.contextmanager
def _own_heap():
    """The collector sees only what the command makes, as in a new interpreter: the test
    process's own objects (pytest, every module other tests imported) are frozen during
    the call. Otherwise each full collection walks them all, a pause of 100-250 ms on a
    loaded machine that starves the threads keeping a device link's heartbeat. Objects
    frozen before (tests/conftest.py freezes what collection made) stay frozen."""
    ours = not RUN_FROZEN and gc.get_freeze_count() == 0
    gc.freeze()
    try:
        yield
    finally:
        if ours:
            gc.unfreeze()


@contextlib.contextmanager
def _interrupt_after(timeout: float, fired: threading.Event):
    """SIGINT to this thread after ``timeout`` s, as ``subprocess.run`` would kill the
    child (here ``main`` ends as at Ctrl-C, and the caller raises ``TimeoutExpired``)."""
    if threading.current_thread() is not threading.main_thread():
        yield                               # signals reach the main thread only
        return
    lock = threading.Lock()
    running = True
    ident = threading.get_ident()

    def fire():
        with lock:
            if running:
                fired.set()
                signal.pthread_kill(ident, signal.SIGINT)

    timer = threading.Timer(timeout, fire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        with lock:
            running = False
        timer.cancel()


def _wait_for_threads(before: set[threading.Thread], timeout: float) -> None:
    """Join the non-daemon threads the command started, as the interpreter does at exit."""
    left = [t for t in threading.enumerate()
            if t not in before and not t.daemon and t is not threading.current_thread()]
    for t in left:
        t.join(timeout)
    alive = [t.name for t in left if t.is_alive()]
    if alive:
        raise AssertionError(f"vtexp left thread(s) {alive} running: a process would not "
                             "exit")


def _encoding() -> str:
    return locale.getpreferredencoding(False)


def _text(f) -> str:
    """The file's bytes as ``subprocess.run(text=True)`` gives them (universal newlines)."""
    f.seek(0)
    data = f.read().decode(_encoding())
    return data.replace("\r\n", "\n").replace("\r", "\n")
