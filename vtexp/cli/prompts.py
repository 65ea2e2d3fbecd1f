"""What vtexp asks the experimenter at the terminal, and how it shows what it found.

Every prompt reads one line with :func:`input`; an input that has ended (a closed
terminal, a pipe) is an answer too: no, or an :class:`~vtexp.errors.InputError`
naming the option that would have given it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import InputError
from ._io import out


def yes(prompt: str) -> bool:
    try:
        return input(prompt).strip().lower() in ("y", "yes")
    except (EOFError, OSError):     # input ended, or the terminal went away
        return False


def status_of(x: dict) -> str:
    status = {"running": "running now" if x.get("held_by") else "did not close (killed?)",
              "interrupted": "interrupted (its process died)"}.get(x["status"], x["status"])
    if x["planned"] is None:
        return f"{status}, no session record"
    return f"{status}, {x['logged']} of {x['planned']} trials"


def describe_session(x: dict) -> str:
    line = f"ses-{x['session']}  {status_of(x)}"
    if x["started"]:
        line += f", started {x['started'][:16].replace('T', ' ')}"
    if x.get("device"):
        line += f", on {x['device']}"
    return line + (f" ({x['reason']})" if x["reason"] else "")


def ask_participant() -> str:
    from ..session import check_participant

    while True:
        try:
            answer = input("Participant id: ").strip()
        except (EOFError, OSError):     # input ended, or the terminal went away
            raise InputError("missing: no participant id was given",
                             key="--participant") from None
        try:
            return check_participant(answer)
        except InputError as e:
            print(f"  {e.message}", flush=True)


def ask_participant_info(participant: str, fields: dict[str, dict], given: dict[str, str],
                         where: Path) -> dict[str, str]:
    """At a participant's first session: each field of participants.tsv not given as an
    option, asked in turn; Enter leaves it n/a, a wrong value is asked again."""
    from .. import bids

    todo = [name for name in fields if name not in given]
    if not todo:
        return given
    out(f"Participant {participant} is new to {where.parent}; what {where.name} records "
        "(Enter leaves a field n/a):")
    info = dict(given)
    for name in todo:
        f = fields[name]
        hint = (", ".join(f["levels"]) if f.get("levels") else
                f"a number{' in ' + f['units'] + 's' if f.get('units') else ''}"
                if f.get("type") == "number" else "one word")
        while True:
            try:
                answer = input(f"  {name} ({hint}): ").strip()
            except (EOFError, OSError):     # input ended: the rest stays n/a
                return info
            try:
                info[name] = bids.check_value(name, f, answer)
                break
            except ValueError as e:
                print(f"    {e}", flush=True)
    return info


def ask_session(participant: str, existing: list[dict], args, lx) -> tuple[int, bool]:
    """The session to run and whether to continue it: the last unfinished session is
    offered first (Enter continues it), else the next free number."""
    from ..errors import SessionError
    from ..session import check_session

    where = Path(args.data) / lx.experiment.name / f"sub-{participant}"
    unfinished = [x for x in existing if x["status"] != "completed" and not x.get("held_by")]
    if existing:
        out(f"Sessions of participant {participant} already in {where}:")
        for x in existing:
            out(f"  {describe_session(x)}")
    else:
        out(f"Participant {participant} has no sessions yet in {where.parent}.")
    if args.resume:
        if not unfinished:
            raise SessionError(f"participant {participant} has no unfinished session in "
                               f"{where.parent} to resume (--resume)")
        default, prompt = unfinished[-1]["session"], "Session to resume"
    else:
        if unfinished:
            last = unfinished[-1]
            if _continue(f"Session {last['session']} did not finish ({status_of(last)}). "
                         "Continue it? [Y/n] "):
                return last["session"], True
        default = max((x["session"] for x in existing), default=0) + 1
        prompt = "New session"
    while True:
        try:
            answer = input(f"{prompt} [{default}]: ").strip()
        except (EOFError, OSError):     # input ended, or the terminal went away
            raise InputError("missing: no session number was given", key="--session") from None
        try:
            session = check_session(int(answer) if answer else default)
        except ValueError:
            print(f"  {answer!r} is not a whole number", flush=True)
            continue
        except InputError as e:
            print(f"  {e.message}", flush=True)
            continue
        known = next((x for x in existing if x["session"] == session), None)
        if args.resume and known not in unfinished:
            print(f"  session {session} is not an unfinished session of participant "
                  f"{participant}; sessions to resume: "
                  + ", ".join(str(x["session"]) for x in unfinished), flush=True)
        elif not args.resume and known is not None:
            print(f"  session {session} already exists ({status_of(known)}); choose another "
                  "number, or stop (Ctrl-C) and continue it with --resume", flush=True)
        else:
            return session, bool(args.resume)


def _continue(prompt: str) -> bool:
    """Yes unless the answer is no (Enter continues the unfinished session)."""
    while True:
        try:
            answer = input(prompt).strip().lower()
        except (EOFError, OSError):
            raise InputError("missing: no answer to whether to continue the unfinished "
                             "session", key="--session") from None
        if answer in ("", "y", "yes"):
            return True
        if answer in ("n", "no"):
            return False
        print("  answer y (continue it) or n (start a new session)", flush=True)


def ask_experimenter(error, trial) -> str:
    """The session pauses on a device fault until the experimenter chooses what to do."""
    print(f"\nThe device failed during trial {trial.number} ({trial.condition.label}):\n"
          f"  {error}\nEvery actuator is off. The session is paused.", file=sys.stderr)
    while True:
        try:
            answer = input("[r]etry the trial (reconnect first), [s]kip it, or [a]bort the "
                           "session? ").strip().lower()
        except (EOFError, OSError):     # input ended, or the terminal went away
            return "abort"
        for choice in ("retry", "skip", "abort"):
            if answer in (choice, choice[0]):
                return choice


def place_object(text: str) -> None:
    """A camera trial: wait until the experimenter has placed the object and pressed Enter.
    A terminal that closes here aborts the session (the trials done are kept)."""
    from ..errors import SessionAborted

    try:
        input(text)
    except (EOFError, OSError):     # input ended, or the terminal went away
        raise SessionAborted("the terminal closed while the object was being placed "
                             "before the camera") from None
