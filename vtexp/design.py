"""Trial lists: conditions x repetitions, in a reproducible order.

The order is a pure function of (experiment name, participant, session) or of
an explicit seed: the same inputs give the same trials on any machine and any
version of numpy or Python, through :mod:`vtexp.seeding` (SHA-256, not a library
generator; :func:`derive_seed`, :class:`HashRandom` and :func:`shuffled` are also
importable from here).
"""

from __future__ import annotations

from dataclasses import dataclass

from .experiment import Experiment
from .model import Condition
from .seeding import HashRandom, derive_seed, shuffled


@dataclass(frozen=True)
class Trial:
    number: int                 # 1-based position in the session (practice trials first)
    condition: Condition
    repetition: int             # 1-based: which presentation of this condition (0: practice)
    practice: bool = False
    block: int = 0              # 1-based block number with order: blocked, else 0
    proposed: float | None = None    # adaptive: the level the procedure asked for
    presented: float | None = None   # adaptive: the level played (the nearest playable)

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


def participant_number(participant: str) -> int:
    """The number that picks a participant's row of a Latin square.

    The digits at the end of the id (``P07`` -> 7, ``12`` -> 12) if it has any, so
    that consecutive participants get consecutive rows; otherwise a number derived
    from the id's hash (stable on every machine).
    """
    digits = ""
    for ch in reversed(participant):
        if not ch.isdigit():
            break
        digits = ch + digits
    if digits:
        return int(digits)
    return derive_seed("latin-square", participant, 0) % 1_000_003


def latin_square_row(n: int, row: int) -> list[int]:
    """Row ``row`` (0-based, taken modulo the square's rows) of a balanced Latin square.

    For an even ``n``, the Williams design: every level precedes every other level
    equally often across the ``n`` rows (first-order carry-over balanced). For an
    odd ``n`` the square has ``2n`` rows, the Williams rows and their reverses, which
    together balance the same way.
    """
    first, lo, hi = [0], 1, n - 1
    while len(first) < n:                          # 0, 1, n-1, 2, n-2, ...
        first.append(lo)
        lo += 1
        if len(first) < n:
            first.append(hi)
            hi -= 1
    rows = n if n % 2 == 0 else 2 * n
    r = row % rows
    seq = [(x + r % n) % n for x in first]
    return seq if r < n else seq[::-1]


def trial_list(experiment: Experiment, conditions: list[Condition], participant: str,
               session: int = 1) -> tuple[list[Trial], int]:
    """The session's trials and the seed that ordered them.

    Each condition appears ``design.repetitions`` times. ``order: sequential``
    keeps declaration order (all repetitions of condition 1, then 2, ...);
    ``order: random`` shuffles the whole list with the seed; ``order: blocked``
    groups the trials by the levels of ``design.block_by``, in the order
    ``design.block_order`` gives (a balanced Latin square row chosen by the
    participant's number, a random order, or the declared one), each block
    shuffled. ``design.practice`` practice trials come first, conditions drawn
    at random with their own stream of the same seed; they are logged but not
    analysed.
    """
    d = experiment.design
    reps = d.repetitions
    seed = trial_seed(experiment, participant, session)
    base = [(c, r) for c in conditions for r in range(1, reps + 1)]
    blocks = [0] * len(base)
    if d.order == "random":
        base = shuffled(base, seed)
    elif d.order == "blocked":
        levels = experiment.factors[d.block_by].level_names
        used = [lv for lv in levels if any(c.levels[d.block_by] == lv for c, _ in base)]
        if d.block_order == "latin_square":
            order = [used[i] for i in latin_square_row(len(used),
                                                       participant_number(participant) - 1)]
        elif d.block_order == "random":
            order = shuffled(used, derive_seed("block-order", str(seed), session))
        else:
            order = used
        grouped, blocks = [], []
        for b, level in enumerate(order, start=1):
            block = [x for x in base if x[0].levels[d.block_by] == level]
            block = shuffled(block, derive_seed(f"block-{b}", str(seed), session))
            grouped += block
            blocks += [b] * len(block)
        base = grouped
    trials: list[Trial] = []
    if d.practice:
        rng = HashRandom(derive_seed("practice", str(seed), session))
        for k in range(1, d.practice + 1):
            c = conditions[rng.below(len(conditions))]
            trials.append(Trial(number=k, condition=c, repetition=0, practice=True))
    # Repetition numbers count presentations in the order they occur.
    seen: dict[int, int] = {}
    for k, ((c, _), b) in enumerate(zip(base, blocks, strict=True), start=len(trials) + 1):
        seen[c.index] = seen.get(c.index, 0) + 1
        trials.append(Trial(number=k, condition=c, repetition=seen[c.index], block=b))
    return trials, seed
