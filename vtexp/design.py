"""Trial lists: conditions x repetitions, in a reproducible order.

The order is a pure function of (experiment name, participant, session) or of
an explicit seed: the same inputs give the same trials on any machine and any
version of numpy or Python. That is why the shuffle does not use numpy's or
Python's generators (whose streams may change between releases) but a
Fisher-Yates shuffle driven by SHA-256 in counter mode, specified here in
full and pinned by a test vector.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from collections.abc import Sequence

from .compile import Condition
from .experiment import Experiment


def derive_seed(experiment: str, participant: str, session: int) -> int:
    """64-bit seed from (experiment, participant, session)."""
    msg = f"vtexp-trial-order\x00{experiment}\x00{participant}\x00{session}".encode()
    return int.from_bytes(hashlib.sha256(msg).digest()[:8], "big")


class HashRandom:
    """Uniform integers from SHA-256(seed, counter): portable and exactly specified."""

    def __init__(self, seed: int):
        self._seed = int(seed).to_bytes(16, "big", signed=True)
        self._counter = 0

    def _u64(self) -> int:
        block = hashlib.sha256(self._seed + self._counter.to_bytes(8, "big")).digest()
        self._counter += 1
        return int.from_bytes(block[:8], "big")

    def below(self, n: int) -> int:
        """Uniform integer in [0, n) by rejection sampling (no modulo bias)."""
        if n <= 0:
            raise ValueError("n must be positive")
        limit = (1 << 64) - ((1 << 64) % n)
        while True:
            x = self._u64()
            if x < limit:
                return x % n

    def random(self) -> float:
        """Uniform float in [0, 1) with 53 bits."""
        return (self._u64() >> 11) / float(1 << 53)


def shuffled(items: Sequence, seed: int) -> list:
    """Fisher-Yates (Durstenfeld) shuffle of ``items`` driven by :class:`HashRandom`."""
    out = list(items)
    rng = HashRandom(seed)
    for i in range(len(out) - 1, 0, -1):
        j = rng.below(i + 1)
        out[i], out[j] = out[j], out[i]
    return out


@dataclass(frozen=True)
class Trial:
    number: int                 # 1-based position in the session
    condition: Condition
    repetition: int             # 1-based: which presentation of this condition

    @property
    def levels(self) -> dict[str, str]:
        return self.condition.levels

    @property
    def stimulus(self) -> str:
        return self.condition.stimulus


def trial_seed(experiment: Experiment, participant: str, session: int) -> int:
    if experiment.design.seed is not None:
        return int(experiment.design.seed)
    return derive_seed(experiment.name, participant, session)


def trial_list(experiment: Experiment, conditions: list[Condition], participant: str,
               session: int = 1) -> tuple[list[Trial], int]:
    """The session's trials and the seed that ordered them.

    Each condition appears ``design.repetitions`` times. ``order: sequential``
    keeps declaration order (all repetitions of condition 1, then 2, ...);
    ``order: random`` shuffles the whole list with the seed.
    """
    reps = experiment.design.repetitions
    seed = trial_seed(experiment, participant, session)
    base = [(c, r) for c in conditions for r in range(1, reps + 1)]
    if experiment.design.order == "random":
        base = shuffled(base, seed)
    # Repetition numbers count presentations in the order they occur.
    seen: dict[int, int] = {}
    trials = []
    for k, (c, _) in enumerate(base, start=1):
        seen[c.index] = seen.get(c.index, 0) + 1
        trials.append(Trial(number=k, condition=c, repetition=seen[c.index]))
    return trials, seed
