"""Seed 000 §4: recognition of the ball per display mode (Fig. 11), the ANOVAs and the
simple effects of Table 3, from logged data.

Usage: python analysis/six_mode_ball.py DATA_DIR [--out DIR]

Prints the recognition rate (% of trials answered "ball", pooled over participants) per
mode, the per-participant rates per mode (Figs. 12-13 show the dynamic ones), then the
analyses experiments/six_mode_ball.yaml declares: static vs dynamic, the 2 x 2 of timing
and intensity over the dynamic modes, and the simple effects of intensity at each timing
(Table 3).
"""

import sys

from common import main

if __name__ == "__main__":
    sys.exit(main("six_mode_ball", [
        ("Recognition rate (%) per mode (Fig. 11)", ["display", "timing"], "intensity",
         "rate", None),
        ("Recognition rate (%) per participant and mode (Figs. 12-13 show the dynamic ones)",
         "participant", ["display", "timing", "intensity"], "rate", None),
    ], __doc__))
