"""Analysis: reads only what sessions wrote, never live objects.

:func:`load_sessions` finds and verifies session folders and builds the tidy
trial table; :mod:`vtexp.analysis.rates` computes recognition rates.
"""

from .load import SessionData, find_sessions, load_sessions, read_session
from .rates import recognition_rates

__all__ = ["SessionData", "find_sessions", "load_sessions", "read_session",
           "recognition_rates"]
