"""Up-down staircases: transformed (Levitt 1971) and weighted (Kaernbach 1991).

A staircase changes the level after each answer by a rule on the run of answers:

- **transformed up-down** (Levitt 1971): the level goes *down* (harder) one step
  after ``n_down`` "yes" (or correct) answers in a row, and *up* one step after
  ``n_up`` "no" answers in a row; the run counters start again after each step.
  The track converges on the level where a step down is as likely as a step up;
  for ``n_up = 1``: :math:`p^{n_{down}} = 1/2`, :math:`p = 0.5^{1/n_{down}}` (1-up-2-down: 70.7 %, 1-up-3-down: 79.4 %;
  Levitt 1971, Table I).
- **weighted up-down** (Kaernbach 1991): one step each answer, with unequal steps.
  At equilibrium :math:`p\\,S_{down} = (1-p)\\,S_{up}`, so the target ``p`` is
  reached with :math:`S_{up} / S_{down} = p / (1-p)` (75 %: up steps three times the
  down steps; Kaernbach 1991, eq. 1).

A *reversal* is a step in the other direction than the step before (the first step
is none). Step sizes may shrink with the reversals: ``steps_down[k]`` is the down
step after ``k`` reversals (the last one repeats), as PsychoPy's ``StairHandler``
``stepSizes``. With ``initial_one_down`` the rule is 1-up-1-down until the first
reversal (Levitt 1971, §V; PsychoPy's ``applyInitialRule``). Levels stay within
``[minimum, maximum]``. The staircase stops after ``max_trials`` answers or
``max_reversals`` reversals, whichever comes first; its estimate is the mean level
at the last ``estimate_reversals`` reversals (Levitt 1971 §V; Wetherill & Levitt 1965).

The state is a pure function of the levels presented and the answers: replaying
them gives the same proposals (``vtexp run --resume`` checks it).

References
----------
Levitt, H. (1971). Transformed up-down methods in psychoacoustics. J. Acoust. Soc. Am.,
49(2B), 467-477.
Kaernbach, C. (1991). Simple adaptive testing with the weighted up-down method.
Perception & Psychophysics, 49(3), 227-229.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


def _down_first(p: float, n_up: int, n_down: int) -> float:
    """The probability that ``n_down`` yes in a row come before ``n_up`` no in a row."""
    # Absorbing chain on the run counter (+k: k yes in a row, -k: k no in a row).
    states = list(range(-(n_up - 1), n_down))
    v = {r: 0.5 for r in states}
    for _ in range(10000):
        new = {}
        for r in states:
            up, down = max(r, 0) + 1, min(r, 0) - 1
            new[r] = (p * (1.0 if up >= n_down else v[up])
                      + (1 - p) * (0.0 if -down >= n_up else v[down]))
        if max(abs(new[r] - v[r]) for r in states) < 1e-15:
            v = new
            break
        v = new
    return v[0]


def target_probability(n_up: int, n_down: int) -> float:
    """The probability of "yes" a transformed up-down staircase converges on: where a
    step down is as likely as a step up (Levitt 1971, Table I).

    For ``n_up = 1`` that is :math:`p^{n_{down}} = 1/2`; in general the probability that
    ``n_down`` yes in a row come before ``n_up`` no in a row is 1/2, solved by bisection.

    >>> round(target_probability(1, 2), 4)
    0.7071
    """
    lo, hi = 1e-9, 1.0 - 1e-9
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if _down_first(mid, n_up, n_down) > 0.5:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def weighted_up_steps(steps_down: tuple[float, ...], target: float) -> tuple[float, ...]:
    """Kaernbach's (1991) up steps for a 1-up-1-down track aiming at ``target``:
    :math:`S_{up} = S_{down}\\,p/(1-p)`."""
    if not 0.0 < target < 1.0:
        raise ValueError("the target probability is between 0 and 1")
    return tuple(s * target / (1.0 - target) for s in steps_down)


@dataclass(frozen=True)
class StaircaseRule:
    """What a staircase does; see the module's docstring."""

    start: float
    steps_down: tuple[float, ...]
    steps_up: tuple[float, ...]
    n_up: int = 1
    n_down: int = 1
    minimum: float = -math.inf
    maximum: float = math.inf
    max_trials: int | None = None
    max_reversals: int | None = None
    initial_one_down: bool = False
    harder: str = "down"              # "down": a yes lowers the level; "up": raises it
    estimate_reversals: int | None = None

    @property
    def target(self) -> float:
        """The probability of "yes" the track converges on."""
        if self.n_up == self.n_down == 1 and self.steps_up != self.steps_down:
            r = self.steps_up[-1] / self.steps_down[-1]
            return r / (1.0 + r)                     # Kaernbach: S_up/S_down = p/(1-p)
        return target_probability(self.n_up, self.n_down)


@dataclass
class Staircase:
    """One staircase track. ``propose()`` the next level, ``update(level, yes)`` after
    the answer; ``finished`` once a stop rule is met."""

    rule: StaircaseRule
    level: float = field(init=False)
    n_trials: int = field(default=0, init=False)
    reversal_levels: list[float] = field(default_factory=list, init=False)
    _run: int = field(default=0, init=False)          # +k: k yes in a row; -k: k no in a row
    _direction: int = field(default=0, init=False)    # last step: -1 down, +1 up, 0 none yet

    def __post_init__(self) -> None:
        self.level = min(max(self.rule.start, self.rule.minimum), self.rule.maximum)

    @property
    def finished(self) -> bool:
        r = self.rule
        return ((r.max_trials is not None and self.n_trials >= r.max_trials)
                or (r.max_reversals is not None and len(self.reversal_levels) >= r.max_reversals))

    def propose(self) -> float:
        """The level of the next trial."""
        return self.level

    def _step(self, direction: int) -> None:
        r = self.rule
        if self._direction and direction != self._direction:
            self.reversal_levels.append(self.level)
        self._direction = direction
        k = len(self.reversal_levels)
        steps = r.steps_down if direction < 0 else r.steps_up
        step = steps[min(k, len(steps) - 1)]
        sign = direction if r.harder == "down" else -direction
        self.level = min(max(self.level + sign * step, r.minimum), r.maximum)

    def update(self, level: float, yes: bool) -> None:
        """Record the answer at ``level`` (the level presented) and take the step the
        rule asks for."""
        r = self.rule
        self.level = level
        self.n_trials += 1
        self._run = (max(self._run, 0) + 1) if yes else (min(self._run, 0) - 1)
        one_down = r.initial_one_down and not self.reversal_levels
        n_down = 1 if one_down else r.n_down
        n_up = 1 if one_down else r.n_up
        if self._run >= n_down:
            self._run = 0
            self._step(-1)
        elif -self._run >= n_up:
            self._run = 0
            self._step(+1)

    def estimate_levels(self) -> list[float]:
        """The reversal levels the estimate averages: the last ``estimate_reversals``, or by
        default all but the first, to an even count (one reversal: that one)."""
        rev = self.reversal_levels
        if not rev:
            return []
        n = self.rule.estimate_reversals
        if n is None:
            n = len(rev) - 1 if len(rev) > 1 else 1
            n -= n % 2 if n > 1 else 0
        return rev[-n:]

    def estimate(self) -> float:
        """The mean level at the reversals of :meth:`estimate_levels` (Levitt 1971 §V);
        the current level if there was no reversal yet."""
        use = self.estimate_levels()
        return sum(use) / len(use) if use else self.level
