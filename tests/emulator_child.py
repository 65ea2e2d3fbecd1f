"""An emulated device in a process of its own (as a real array is apart from the host), for
tests that audit what it drove while the host is busy.

Usage: python emulator_child.py PROFILE OUT_JSON
Prints "port /dev/pts/N" once serving; when standard input closes, writes every actuation
the firmware made to OUT_JSON as [t_us, index, kind, values...] rows and exits.
"""

import json
import sys

from vtexp.devices.emulator import PtyEmulator
from vtexp.devices.wire import Level
from vtexp.model import DeviceProfile

profile, out = DeviceProfile.load(sys.argv[1]), sys.argv[2]
emu = PtyEmulator.for_profile(profile)
print("port", emu.start(), flush=True)
try:
    sys.stdin.read()
finally:
    rows = []
    for a in emu.actuations():
        s = a.setting
        if isinstance(s, Level):
            rows.append([a.t_us, a.index, "level", s.level])
        else:
            rows.append([a.t_us, a.index, "train", s.amplitude_mv, s.frequency_chz, s.width_us])
    emu.stop()
    with open(out, "w") as f:
        json.dump({"actuations": rows, "all_off": all(s.is_off for s in emu.outputs())}, f)
