"""Seed 002 §4: the whirlpool ratings and turns counted, with and without phantom points
at 25, 40 and 50 Hz (Figs. 12-17), from logged data.

Usage: python analysis/whirlpool.py DATA_DIR [--out DIR]

Prints the mean rating (0 no feeling ... 4 whirlpool) and the mean number of turns per
phantom condition and frequency, pooled over participants, the ratings per participant
(the paper's figures show each subject), then the analyses experiments/whirlpool.yaml
declares (ANOVA and Friedman tests on the ratings, ANOVA on the turns).
"""

import sys

from common import main

if __name__ == "__main__":
    sys.exit(main("whirlpool", [
        ("Mean rating per phantom condition and frequency (Figs. 12-17)", "phantom",
         "frequency", "answer", "sensation"),
        ("Mean turns counted per phantom condition and frequency", "phantom", "frequency",
         "answer", "turns"),
        ("Mean rating per participant", "participant", ["phantom", "frequency"], "answer",
         "sensation"),
    ], __doc__))
