"""Does the device check survive a noisy line? The emulator's link and the simulated chip's.

``vtexp run`` checks the device before the first trial (``check_ready``: identity, 20
round trips, every actuator off). Here that check runs while the line is damaged, and
the table counts the runs in which the session survived (the host did not declare the
device lost):

- a byte error rate of 1e-2 in both directions (the emulator: half dropped, half
  altered; the ATmega2560 build in simavr: a third each dropped, altered and
  inserted), from the first round trip on;
- the line cut in both directions for a while (every byte dropped), from the first
  round trip on.

Rows: the Python emulator in-process on a virtual clock with the default link (200 ms
heartbeat, 25 ms reply wait), and the ATmega2560 build in simavr, paced to the wall
clock, with the link ``vtexp device emulate --firmware avr`` suggests (1 s heartbeat,
reply wait from :func:`vtexp.devices.link.suggested_reply_ms`) and with the one it
suggested before (1 s, 250 ms). A cut longer than the silence limit (0.6 of the
heartbeat period) is a pulled cable for the host, by design (docs/protocol.md), whatever
the reply wait.

Prints a table, writes bench/results/link_faults.json.
Usage: python bench/link_faults.py [--runs 10] [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.clock import VirtualClock  # noqa: E402
from vtexp.devices import open_device  # noqa: E402
from vtexp.devices.check import check_ready  # noqa: E402
from vtexp.devices.emulator import Faults  # noqa: E402
from vtexp.devices.link import suggested_reply_ms  # noqa: E402
from vtexp.errors import DeviceError  # noqa: E402
from vtexp.model import DeviceProfile  # noqa: E402

VEST = DeviceProfile.load("vest_6x8")


def emulator_check(fault: str, seed: int) -> bool:
    clock = VirtualClock()
    dev = open_device("emulator", VEST, clock=clock)
    try:
        dev.open()
        emu = dev.emulator
        if fault == "ber":
            emu.faults = Faults(drop_rate=0.005, corrupt_rate=0.005, seed=seed)
        else:
            emu.faults = Faults(drop_rate=1.0, seed=seed)
            clock.call_later(float(fault[4:]), lambda: setattr(emu, "faults", Faults()))
        check_ready(dev, VEST, pings=20, say=lambda s: None)
        return True
    except DeviceError:
        return False
    finally:
        try:
            dev.close()
        except DeviceError:
            pass


def avr_check(fault: str, seed: int, reply_ms: int) -> bool:
    from vtexp.devices.cfirmware import AvrSimulator

    with AvrSimulator("vest_6x8", seed=seed) as sim:
        dev = open_device(f"serial:{sim.port},heartbeat_ms=1000,reply_ms={reply_ms}", VEST)
        mend = threading.Timer(float(fault[4:] or 0), lambda: sim.command("faults 0 0 0"))
        try:
            dev.open()
            if fault == "ber":
                sim.command("faults 0.0034 0.0033 0.0033")
            else:
                sim.command("faults 1 0 0")
                mend.start()
            check_ready(dev, VEST, pings=20, say=lambda s: None)
            return True
        except DeviceError:
            return False
        finally:
            mend.cancel()
            if mend.ident is not None:          # started (a cut): wait until it is mended
                mend.join()
            sim.command("faults 0 0 0")
            try:
                dev.close()
            except DeviceError:
                pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--quick", action="store_true", help="3 runs each")
    a = ap.parse_args()
    runs = 3 if a.quick else a.runs
    faults = {"ber": "byte errors 1e-2", "cut:0.45": "cut 0.45 s", "cut:1.0": "cut 1 s"}
    links = {"emulator (200 ms, 25 ms)": None,
             f"avr (1000 ms, {suggested_reply_ms(1000)} ms)": suggested_reply_ms(1000),
             "avr (1000 ms, 250 ms; before)": 250}
    t0 = time.monotonic()
    res: dict = {}
    for name, reply in links.items():
        res[name] = {}
        for f in faults:
            ok = sum(emulator_check(f, s) if reply is None else avr_check(f, s, reply)
                     for s in range(1, runs + 1))
            res[name][faults[f]] = {"survived": ok, "runs": runs}
    w = max(map(len, links))
    print(f"Device check (20 round trips) on a damaged line: sessions that survived, of "
          f"{runs}\n")
    print(f"{'link (heartbeat, reply wait)':{w}}  " + "  ".join(f"{v:>16}" for v in
                                                                faults.values()))
    for name, row in res.items():
        print(f"{name:{w}}  " + "  ".join(f"{row[v]['survived']:>13d}/{runs:<2d}"
                                          for v in faults.values()))
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "link_faults.json").write_text(json.dumps(
        {"runs": runs, "results": res, "seconds": round(time.monotonic() - t0)},
        indent=2) + "\n")
    print(f"\nwrote bench/results/link_faults.json ({round(time.monotonic() - t0)} s)")


if __name__ == "__main__":
    main()
