"""Analysis: reads only what sessions wrote, never live objects.

:func:`load_sessions` finds and verifies session folders and builds the tidy
trial table; the statistics (:mod:`.anova`, :mod:`.posthoc`, :mod:`.ordinal`,
:mod:`.confusion`, :mod:`.glmm`) each take a tidy table and return one;
:mod:`.pipeline` runs an experiment's declared analyses (:mod:`.spec`) and
:mod:`.report` only formats what they return.

Names are imported lazily, so that ``vtexp.experiment`` can use the
``analysis:`` schema (:mod:`.spec`) without importing pandas and scipy.
"""

from __future__ import annotations

import importlib

_NAMES = {
    "SessionData": "load", "find_sessions": "load", "load_sessions": "load",
    "read_session": "load", "recognition_rates": "rates",
    "rm_anova": "anova", "rm_anova_batch": "anova", "simple_effects": "anova",
    "MissingCellsWarning": "anova", "pairwise_tests": "posthoc", "p_adjust": "posthoc",
    "friedman": "ordinal", "wilcoxon_pairwise": "ordinal",
    "confusion_matrix": "confusion", "information_transfer": "confusion",
    "agreement": "confusion", "mixed_logit": "glmm",
}

__all__ = sorted(_NAMES)


def __getattr__(name: str):
    if name in _NAMES:
        return getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
