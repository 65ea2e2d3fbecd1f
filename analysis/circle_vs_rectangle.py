"""Seed 002 §4: circle or rectangle rated -2 (rectangle) ... +2 (circle), without and with
corner emphasis (Figs. 19-20), from logged data.

Usage: python analysis/circle_vs_rectangle.py DATA_DIR [--out DIR]

Prints the mean rating per shape and corner condition, pooled over participants, the
ratings per participant (the paper's figures show each subject), then the analyses
experiments/circle_vs_rectangle.yaml declares.
"""

import sys

from common import main

if __name__ == "__main__":
    sys.exit(main("circle_vs_rectangle", [
        ("Mean rating per shape and corner emphasis (Figs. 19-20)", "shape", "corners",
         "answer", None),
        ("Mean rating per participant", "participant", ["shape", "corners"], "answer", None),
    ], __doc__))
