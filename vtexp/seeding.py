"""Seeded randomness that is the same on every machine and every version.

The trial order, a scripted responder's answers and QUEST+'s draws among its best
levels are pure functions of a seed. That is why they do not use numpy's or Python's
generators (whose streams may change between releases) but SHA-256: a seed derived
from names (:func:`derive_seed`), uniform numbers from SHA-256 in counter mode
(:class:`HashRandom`) and a Fisher-Yates shuffle driven by them (:func:`shuffled`),
specified here in full and pinned by test vectors (tests/test_design.py).

This module imports nothing of vtexp, so that any part of it can draw from it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence


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
