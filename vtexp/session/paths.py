"""Who and where: participant and session ids, and where a session's files are."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from .. import bids
from ..errors import InputError

PARTICIPANT = re.compile(r"^[A-Za-z0-9]{1,64}$")

#: Participant ids that start with this (any case) belong to model participants only,
#: so that a simulated session can never be taken for a person's.
SIMULATED_PREFIX = "sim"


def check_participant(participant: str) -> str:
    """A participant id is a BIDS label: letters and digits only (no '/', '..', '_')."""
    if not isinstance(participant, str) or not PARTICIPANT.match(participant):
        raise InputError(f"participant id {participant!r} is not a plain token; use 1-64 "
                         "letters and digits (e.g. 01, P07, anna)", key="--participant")
    return participant


def participant_kind(responder: object) -> str:
    """Who answers: ``person`` (window, console), ``model`` (a model participant) or
    ``scripted`` (answers from a rule or a file)."""
    return str(getattr(responder, "participant_kind", "person"))


def check_participant_kind(participant: str, kind: str) -> None:
    """Model participants and people never share an id: ``sim...`` is the models'."""
    simulated_id = participant.lower().startswith(SIMULATED_PREFIX)
    if kind == "model" and not simulated_id:
        raise InputError(f"a model participant's id starts with '{SIMULATED_PREFIX}' (e.g. "
                         f"{SIMULATED_PREFIX}{participant}), so that its sessions are never "
                         f"taken for a person's; got {participant!r}", key="--participant")
    if kind == "person" and simulated_id:
        raise InputError(f"ids starting with '{SIMULATED_PREFIX}' are kept for model "
                         f"participants; give this person another id (got {participant!r})",
                         key="--participant")


def check_session(session: int) -> int:
    if not isinstance(session, int) or session < 1 or session > 9999:
        raise InputError(f"session must be a whole number from 1 to 9999 (got {session!r})",
                         key="--session")
    return session


def device_kind(spec_or_backend: str | None) -> str:
    """``serial:/dev/ttyACM0`` -> ``serial``; ``sim:realtime`` -> ``sim``."""
    return (spec_or_backend or "").partition(":")[0]


@dataclass(frozen=True)
class SessionPaths:
    """Where one session's files are in its dataset (``root``, the experiment's folder)."""

    root: Path
    participant: str
    session: int
    task: str

    @classmethod
    def of(cls, data_dir: Path | str, experiment: str, task: str, participant: str,
           session: int) -> SessionPaths:
        return cls(Path(data_dir) / experiment, participant, session, task)

    @property
    def prefix(self) -> str:
        return f"sub-{self.participant}_ses-{self.session}_task-{self.task}"

    @property
    def dir(self) -> Path:
        """The session's BIDS files: ``sub-<P>/ses-<N>/beh/``."""
        return self.root / f"sub-{self.participant}" / f"ses-{self.session}" / "beh"

    @property
    def record_dir(self) -> Path:
        """vtexp's record, lock and camera frames: ``sourcedata/vtexp/sub-<P>/ses-<N>/``."""
        return self.root / bids.SOURCE / f"sub-{self.participant}" / f"ses-{self.session}"

    @property
    def beh_tsv(self) -> Path:
        return self.dir / f"{self.prefix}_beh.tsv"

    @property
    def beh_json(self) -> Path:
        return self.dir / f"{self.prefix}_beh.json"

    @property
    def events_tsv(self) -> Path:
        return self.dir / f"{self.prefix}_events.tsv"

    @property
    def events_json(self) -> Path:
        return self.dir / f"{self.prefix}_events.json"

    @property
    def session_json(self) -> Path:
        return self.record_dir / f"{self.prefix}_session.json"

    def relative(self, path: Path) -> str:
        """A file's path from the dataset's root, as the record names it."""
        return path.relative_to(self.root).as_posix()
