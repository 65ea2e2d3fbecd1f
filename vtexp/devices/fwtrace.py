"""What the firmware drove, read from vtexp-simavr's cycle-stamped trace.

The harness records the chip's pins, not what the firmware believes: the SPI
bytes shifted before each rising edge of the chain's latch (the TPIC6B595s' RCK,
or the LTC2656s' CS/LD), output enable (with its pull-up), the sync output, and
the SMA gate ports. This module turns that back into outputs over time:

- level drives: the chain's storage registers after each latch, one bit per
  actuator (actuator i is bit i % 8 of chip i / 8; the farthest chip's byte is
  shifted first), forced off while output enable is high;
- pulse trains: each pin's gate edges, and the amplitude its DAC channel held
  (LTC2656 32-bit words, farthest chip first: command 0011 writes channel n).

Times are CPU cycles at 16 MHz (``us(c)``). Tests use it to prove what the chip
did; ``bench/firmware.py`` to measure it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HZ = 16_000_000
DAC_FULL_SCALE_CODE = 4095


def us(cycles: float) -> float:
    """Cycles of the 16 MHz clock to microseconds."""
    return cycles * 1e6 / HZ


@dataclass
class Trace:
    """A vtexp-simavr trace, parsed (see the module docstring)."""

    latches: list[tuple[int, bytes]] = field(default_factory=list)
    oe: list[tuple[int, int]] = field(default_factory=list)
    sync: list[tuple[int, int]] = field(default_factory=list)
    ports: list[tuple[int, str, int]] = field(default_factory=list)
    rx0: list[int] = field(default_factory=list)
    rx_frames: list[tuple[int, int]] = field(default_factory=list)   # (cycle, encoded bytes)
    tx0: list[int] = field(default_factory=list)
    resets: list[int] = field(default_factory=list)
    wall: list[tuple[int, int]] = field(default_factory=list)
    end: dict = field(default_factory=dict)
    stack_used: int | None = None
    #: cycles from each tick's timer compare to its interrupt handler: {cycles: count}
    tick_latency: dict[int, int] = field(default_factory=dict)
    #: the worst of them: cycles, the cycle the tick was due, and the program counter
    #: (byte address) and interrupt vector (0: none) that held it off
    tick_latency_worst: dict = field(default_factory=dict)
    peeks: dict[int, bytes] = field(default_factory=dict)
    clock_start: int | None = None      # cycle at which the firmware started Timer1

    def device_us(self, cycle: int) -> float:
        """The firmware's clock (us since it started Timer1) at ``cycle``."""
        assert self.clock_start is not None, "the firmware never started its clock"
        return (cycle - self.clock_start) / (HZ / 1e6)

    def cycle_of(self, device_us: float) -> float:
        assert self.clock_start is not None, "the firmware never started its clock"
        return self.clock_start + device_us * (HZ / 1e6)

    @classmethod
    def load(cls, path: str | Path) -> Trace:
        t = cls()
        with open(path, encoding="utf-8") as f:
            for line in f:
                try:
                    d = json.loads(line)
                except ValueError:
                    continue                  # a line cut off by a kill
                e, c = d["e"], d.get("c", 0)
                if e == "latch":
                    t.latches.append((c, bytes.fromhex(d["d"])))
                elif e == "oe":
                    t.oe.append((c, d["v"]))
                elif e == "sync":
                    t.sync.append((c, d["v"]))
                elif e == "port":
                    t.ports.append((c, d["p"], d["v"]))
                elif e == "rx0":
                    t.rx0.append(c)
                    if d.get("n"):
                        t.rx_frames.append((c, d["n"]))
                elif e == "tx0":
                    t.tx0.append(c)
                elif e == "reset":
                    t.resets.append(c)
                    t.clock_start = None          # the firmware starts its clock again
                elif e == "wall":
                    t.wall.append((c, d["ns"]))
                elif e == "stack":
                    t.stack_used = d["used"]
                elif e == "tick_latency":
                    t.tick_latency = {int(k): v for k, v in d["hist"].items()}
                    t.tick_latency_worst = {"cycles": d["worst"], "at": d["worst_at"],
                                            "pc": d["worst_pc"], "vector": d["worst_vector"],
                                            "handler": d.get("handler_worst"),
                                            "handler_at": d.get("handler_worst_at")}
                elif e == "peek":
                    t.peeks[d["a"]] = bytes.fromhex(d["d"])
                elif e == "end":
                    t.end = d
                elif e == "clock" and t.clock_start is None:
                    t.clock_start = c
        return t

    @property
    def sync_rises(self) -> np.ndarray:
        return np.array([c for c, v in self.sync if v], dtype=np.int64)

    def oe_off_at(self, cycle: int) -> bool:
        """Output enable high (drains off) at ``cycle``; high before the firmware drove it."""
        state = 1
        for c, v in self.oe:
            if c > cycle:
                break
            state = v
        return bool(state)


# --------------------------------------------------------------------------- level drives

@dataclass
class ChainOutputs:
    """The chain's outputs after each latch: ``cycles[k]`` and ``bits[k, i]`` (actuator i
    on), with output enable applied; ``oe_off`` lists the cycles where it went high."""

    cycles: np.ndarray
    bits: np.ndarray

    def on_runs(self, index: int) -> list[tuple[int, int]]:
        """Latch positions ``(first, last)`` of each run of latches with ``index`` on."""
        b = self.bits[:, index].astype(np.int8)
        d = np.diff(np.concatenate([[0], b, [0]]))
        return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


def chain_outputs(trace: Trace, n_actuators: int) -> ChainOutputs:
    """Replay the TPIC6B595 chain: the shift registers, and the storage registers at each
    latch; an output drives only while output enable is low."""
    nb = (n_actuators + 7) // 8
    shift = bytearray(nb)           # shift[c] = what chip c holds
    cycles, states = [], []
    oe_events = sorted(trace.oe)
    k_oe, oe = 0, 1
    for c, data in trace.latches:
        for byte in data:               # each byte enters chip 0 and pushes the others on
            shift[1:] = shift[:-1]
            shift[0] = byte
        while k_oe < len(oe_events) and oe_events[k_oe][0] <= c:
            oe = oe_events[k_oe][1]
            k_oe += 1
        cycles.append(c)
        states.append(bytes(shift) if not oe else bytes(nb))
    # output enable going high between latches turns everything off at that instant
    for c, v in oe_events:
        if v:
            cycles.append(c)
            states.append(bytes(nb))
    order = np.argsort(np.array(cycles, dtype=np.int64), kind="stable")
    cyc = np.array(cycles, dtype=np.int64)[order]
    raw = np.frombuffer(b"".join(states), dtype=np.uint8).reshape(-1, nb)[order]
    bits = np.unpackbits(raw, axis=1, bitorder="little")[:, :n_actuators].astype(bool)
    return ChainOutputs(cyc, bits)


@dataclass(frozen=True)
class LevelPulse:
    """A pulse seen on the chain: its actuator, the latch that turned it on, the latch
    that left it off, and the on slots of its carrier period (its level's duty)."""

    index: int
    start: int          # cycle of the latch that turned it on
    end: int            # cycle of the latch that left it off for good
    on_slots: int


def level_pulses(trace: Trace, n_actuators: int, slots: int = 10) -> list[LevelPulse]:
    """Split each actuator's output into pulses, from the pins alone.

    The firmware restarts the carrier at every onset and raises sync with that latch,
    so every pulse begins at a sync latch, on for its level's slots of each 10-slot
    period. At a sync latch an actuator that is on starts a pulse unless it was
    already in one (on within the last period) at the same duty; a pulse ends after
    its last on latch.
    """
    out = chain_outputs(trace, n_actuators)
    rises = set(trace.sync_rises.tolist())
    cyc = out.cycles
    syncs = [k for k, c in enumerate(cyc) if int(c) in rises]
    pulses: list[LevelPulse] = []
    for i in range(n_actuators):
        b = out.bits[:, i]
        open_start: int | None = None     # latch position of the pulse in progress
        open_run = 0
        starts: list[tuple[int, int]] = []
        for n, k in enumerate(syncs):
            if not b[k]:
                continue
            nxt = syncs[n + 1] if n + 1 < len(syncs) else len(b)
            run = 0
            while k + run < nxt and run < slots and b[k + run]:
                run += 1
            was_on = bool(b[max(0, k - slots):k].any())
            if was_on and open_start is not None and run == open_run:
                continue                  # the same pulse, its carrier restarted
            starts.append((k, run))
            open_start, open_run = k, run
        for n, (k, run) in enumerate(starts):
            nxt = starts[n + 1][0] if n + 1 < len(starts) else len(b)
            seg = np.flatnonzero(b[k:nxt])
            last = k + int(seg[-1])
            end_k = min(last + 1, len(b) - 1)
            pulses.append(LevelPulse(i, int(cyc[k]), int(cyc[end_k]), run))
    pulses.sort(key=lambda p: (p.start, p.index))
    return pulses


def duty_per_level(trace: Trace, n_actuators: int, slots: int = 10) -> dict[int, set[int]]:
    """Actuator index → the on-slot counts seen in whole carrier periods of its pulses."""
    out = chain_outputs(trace, n_actuators)
    seen: dict[int, set[int]] = {}
    rises = set(trace.sync_rises.tolist())
    onset_pos = [k for k, c in enumerate(out.cycles) if int(c) in rises]
    for i in range(n_actuators):
        b = out.bits[:, i]
        for n, k in enumerate(onset_pos):
            if not b[k]:
                continue
            nxt = onset_pos[n + 1] if n + 1 < len(onset_pos) else len(b)
            for p in range(k, nxt - slots + 1, slots):       # whole periods only
                window = b[p:p + slots]
                if p + slots <= nxt and window.any():
                    seen.setdefault(i, set()).add(int(window.sum()))
    return seen


# --------------------------------------------------------------------------- pulse trains

PORT_BASE = {"A": 0, "C": 8, "L": 16, "G": 24}


def gate_edges(trace: Trace, n_pins: int = 25) -> dict[int, list[tuple[int, int]]]:
    """Pin → ``[(cycle, 0 | 1)]``: each change of its gate."""
    state = [0] * n_pins
    out: dict[int, list[tuple[int, int]]] = {i: [] for i in range(n_pins)}
    for c, p, v in trace.ports:
        base = PORT_BASE[p]
        width = 1 if p == "G" else 8
        for b in range(width):
            i = base + b
            if i >= n_pins:
                continue
            s = (v >> b) & 1
            if s != state[i]:
                state[i] = s
                out[i].append((c, s))
    return out


def dac_codes(trace: Trace, chips: int = 4) -> list[tuple[int, int, int]]:
    """``[(cycle, pin, code)]``: each change of a DAC channel's output (LTC2656,
    daisy-chained; a 32-bit word per chip, the farthest first, executed as CS/LD rises).

    The chips are modelled as the datasheet has them (Table 1): command 0000 writes the
    input register of channel n, 0001 updates the DAC register of n from it, 0010 writes
    input n and updates all, 0011 writes and updates n; address 1111 is every channel.
    An update of a channel whose input register was never written changes nothing.
    """
    out = []
    inp: dict[int, int] = {}                       # input registers, by pin

    def update(c: int, pin: int) -> None:
        if pin in inp:
            out.append((c, pin, inp[pin]))

    for c, data in trace.latches:
        if len(data) != 4 * chips:
            continue
        for k in range(chips):
            chip = chips - 1 - k
            w = data[4 * k:4 * k + 4]
            cmd, addr = w[1] >> 4, w[1] & 0xF
            targets = range(8) if addr == 0xF else (addr,) if addr < 8 else ()
            code = ((w[2] << 8) | w[3]) >> 4
            if cmd in (0x0, 0x2, 0x3):
                for ch in targets:
                    inp[chip * 8 + ch] = code
            if cmd in (0x1, 0x3):
                for ch in targets:
                    update(c, chip * 8 + ch)
            elif cmd == 0x2:
                for ch in range(8):
                    update(c, chip * 8 + ch)
    return out


def code_to_mv(code: int, full_scale_mv: int) -> int:
    return round(code * full_scale_mv / DAC_FULL_SCALE_CODE)


@dataclass(frozen=True)
class Train:
    """A pulse train seen on a pin: first rise, last fall, pulses (rise, fall) in cycles,
    and the amplitude its DAC channel held at the first rise."""

    index: int
    pulses: tuple[tuple[int, int], ...]
    code: int | None

    @property
    def start(self) -> int:
        return self.pulses[0][0]

    @property
    def widths_us(self) -> list[float]:
        return [us(f - r) for r, f in self.pulses]

    @property
    def periods_us(self) -> list[float]:
        return [us(b[0] - a[0]) for a, b in zip(self.pulses, self.pulses[1:])]


def pin_pulses(trace: Trace, n_pins: int = 25) -> dict[int, list[tuple[int, int]]]:
    """Pin → ``[(rise cycle, fall cycle)]``: every pulse its gate made (one still high at
    the end of the trace is left out)."""
    out: dict[int, list[tuple[int, int]]] = {}
    for i, edges in gate_edges(trace, n_pins).items():
        pulses = out[i] = []
        rise = None
        for c, s in edges:
            if s:
                rise = c
            elif rise is not None:
                pulses.append((rise, c))
                rise = None
    return out


def trains(trace: Trace, n_pins: int = 25, gap_us: float = 100_000.0) -> list[Train]:
    """Group each pin's pulses into trains: a new train starts at a sync edge (an onset)
    or after ``gap_us`` without a pulse, unless the pulse comes one period after the
    train's last (then another pin's onset fell on the same tick). A train's second
    pulse falling on another pin's onset cannot be told apart: it starts a train."""
    rises = trace.sync_rises
    codes = dac_codes(trace)
    out: list[Train] = []
    for i, pulses in pin_pulses(trace, n_pins).items():
        group: list[tuple[int, int]] = []
        for r, f in pulses:
            onset = bool(len(rises)) and int(np.min(np.abs(rises - r))) <= 64
            if len(group) >= 2:
                # the train's own next pulse is a period after the last: that is no new
                # train, even when another pin's onset falls on the same tick
                period = group[-1][0] - group[-2][0]
                on_time = abs(r - group[-1][0] - period) <= 1600        # one 100 us tick
                new = not on_time and (onset or us(r - group[-1][0]) > gap_us)
            else:
                new = bool(group) and (onset or us(r - group[-1][0]) > gap_us)
            if new:
                out.append(_train(i, group, codes))
                group = []
            group.append((r, f))
        if group:
            out.append(_train(i, group, codes))
    out.sort(key=lambda t: (t.start, t.index))
    return out


def _train(i: int, pulses: list[tuple[int, int]], codes) -> Train:
    at = pulses[0][0]
    code = None
    for c, pin, v in codes:
        if pin == i and c <= at:
            code = v
    return Train(i, tuple(pulses), code)




# --------------------------------------------------------------------------- what was driven

def level_slots(profile) -> list[int]:
    """PWM slots (of 10) of each level, from the profile's duties (as the firmware's
    profile header has them)."""
    return [round(lv.duty * 10) for lv in profile.drive.levels]


def driven(trace: Trace, profile) -> list[tuple[int, object]]:
    """``[(actuator, wire setting)]`` for every pulse the chip drove, read from its pins:
    the level from a pulse's duty, or a train's amplitude (its DAC channel), frequency
    (the first period) and width (the first pulse)."""
    from .wire import Level
    from .wire import Train as WireTrain

    n = profile.rows * profile.cols
    if profile.drive.kind == "levels":
        slots = level_slots(profile)
        inverse = {s: lv for lv, s in enumerate(slots) if lv}
        return [(p.index, Level(inverse.get(p.on_slots, -p.on_slots)))
                for p in level_pulses(trace, n)]
    full_scale = round(1000 * max(profile.drive.amplitude_v, profile.limits.max_amplitude_v or 0))
    out = []
    for tr in trains(trace, n):
        period = tr.periods_us[0] if tr.periods_us else None
        out.append((tr.index, WireTrain(
            code_to_mv(tr.code, full_scale) if tr.code is not None else -1,
            round(1e8 / period) if period else 0, round(tr.widths_us[0]))))
    return out


def host_driven(path: str | Path) -> list[tuple[int, object]]:
    """The same from vtexp-fw-host's record of its outputs: every switch on."""
    from .wire import Level
    from .wire import Train as WireTrain

    state: dict[int, tuple] = {}
    out = []
    for d in _host_records(path):
        if d.get("off"):
            state.clear()
            continue
        for i, a, fr, w in d.get("set", []):
            if a and state.get(i) != (a, fr, w):
                out.append((i, Level(a) if fr == 0 and w == 0 else WireTrain(a, fr, w)))
            state[i] = (a, fr, w) if a else None
    return out


def host_all_off(path: str | Path) -> bool:
    """vtexp-fw-host's outputs are all off at the end of its record."""
    state: dict[int, int] = {}
    for d in _host_records(path):
        if d.get("off"):
            state.clear()
        for i, a, _, _ in d.get("set", []):
            state[i] = a
    return not any(state.values())


def _host_records(path: str | Path):
    """vtexp-fw-host's record, one JSON object per line (a line cut short by a killed
    process is skipped)."""
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                yield json.loads(line)
            except ValueError:
                continue


def all_off_at_end(trace: Trace, n_actuators: int) -> bool:
    """Every output off at the end of the trace (the last latch, or output enable)."""
    if trace.ports or not trace.latches:
        edges = gate_edges(trace, n_actuators)
        return all(not e or e[-1][1] == 0 for e in edges.values())
    out = chain_outputs(trace, n_actuators)
    return not out.bits[-1].any()
