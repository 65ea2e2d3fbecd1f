"""Damaged and odd inputs of every family vtexp reads (``tests/fuzz.py``): each is refused
with one message, or accepted whole; never a traceback, a hang or a silent acceptance.

Every run of the suite tries a few seeded cases per family; ``pytest tests/test_fuzz.py
--fuzz-long N`` tries N per family, and ``bench/fuzz.py`` prints the outcomes as a table.
"""

from __future__ import annotations

import pytest

from fuzz import FAMILIES, run_family

#: cases per family on every run of the suite (each a few tenths of a second)
FAST = {"experiment": 10, "coding": 6, "image": 6, "stats": 12, "dataset": 6}


@pytest.mark.parametrize("family", FAMILIES)
def test_damaged_inputs_are_refused_with_a_message_or_accepted_whole(family, tmp_path,
                                                                     request):
    n = request.config.getoption("--fuzz-long") or FAST[family]
    cases = run_family(family, range(n), tmp_path)
    bad = [c for c in cases if c.outcome not in ("refused", "accepted")]
    assert not bad, "\n".join(f"{c.family} seed {c.seed}: {c.outcome}: {c.detail} "
                              f"(after {', '.join(c.mutations)})" for c in bad)
    assert any(c.outcome == "refused" for c in cases), [c.mutations for c in cases]


@pytest.mark.parametrize("family", ["experiment", "coding", "image", "stats"])
def test_the_undamaged_inputs_are_accepted(family, tmp_path, monkeypatch):
    """The control: with every mutation a no-op, each family's cases are accepted (so a
    refusal above is the damage's, not the harness's)."""
    import fuzz
    monkeypatch.setattr(fuzz, "mutate_text", lambda text, kind, rng, said: text)
    monkeypatch.setattr(fuzz, "mutate_bytes", lambda data, rng, said: data)
    cases = run_family(family, range(4), tmp_path)
    assert all(c.outcome == "accepted" for c in cases), \
        [(c.mutations, c.outcome, c.detail) for c in cases]
