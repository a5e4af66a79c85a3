"""The command side of the tracker: the set-points it aims at, the known excursions around them,
the commands on their way (a rig's latency) and where the delay lines are (their lag), and the
count of readings and steps that the rest of the state is timed by.
"""

from __future__ import annotations

import functools
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .fit import wrap
from .params import TrackerParams

#: Steps between readings over which the lagging lines are followed (the newest command).
MAX_LAG_STEPS = 100


@dataclass
class Loop:
    """Commands and readings of one run (from a reset); set-points in cycles of the model."""

    base: np.ndarray  # set-points around which the excursions are made
    last_command: np.ndarray
    acting: np.ndarray  # with a latency: the set-points acting on the delay lines now
    position: np.ndarray  # the delay lines' positions (a lag)
    # with a latency: commands on their way, [step it acts at without latency, set-points,
    # whole-cycle move]
    in_flight: deque = field(default_factory=deque)
    awaiting: bool = False  # a command was given and its reading has not come yet
    revise: bool = False  # think() changed the command given: command() gives it anew
    hop: tuple | None = None  # (stage, cycles) of the whole-cycle move in the command just sent
    tick: int = 0  # readings taken
    step: int = 0  # simulator (or rig) steps up to the latest reading
    gap: int = 1  # steps between the last two readings
    last_power: float = float("nan")

    @classmethod
    def start(cls, u: np.ndarray) -> Loop:
        return cls(base=u.copy(), last_command=u.copy(), acting=u.copy(), position=u.copy())

    def aim(self, target: np.ndarray) -> None:
        """Aim at ``target`` by the smallest move modulo a period."""
        self.base = self.base + wrap(target - self.base)

    def send(self, u: np.ndarray, latency: int) -> None:
        """``u`` is the command given now."""
        self.last_command = u
        self.awaiting = True
        if latency:
            self.in_flight.append([self.step + 1, u.copy(), self.hop])
            self.hop = None

    def reading(self, power: float, steps: int) -> None:
        """A reading came, ``steps`` steps after the one before."""
        self.awaiting = False
        self.last_power = float(power)
        self.tick += 1
        self.step += steps
        self.gap = steps

    def command_taken(self, taken: int, expected: int) -> None:
        """The last command, expected at step ``expected``, was taken at step ``taken``: it acts
        from ``taken`` + latency."""
        if taken > expected and self.in_flight and self.in_flight[-1][0] == expected:
            self.in_flight[-1][0] = taken

    def reading_setpoints(self, latency: int, lag_gain: float | None):
        """(set-points, whole-cycle move) that shaped the reading at ``step``: the last command,
        or with latency the one in effect ``latency`` steps before; with a lag, where the delay
        lines got to on their way to it."""
        if not latency:
            hop, self.hop = self.hop, None
            acting = self.last_command
        else:
            hop = None
            while self.in_flight and self.in_flight[0][0] <= self.step - latency:
                _, self.acting, moved = self.in_flight.popleft()
                hop = moved if moved is not None else hop
            acting = self.acting
        if lag_gain is None:
            return acting, hop
        for _ in range(min(self.gap, MAX_LAG_STEPS)):
            self.position = self.position + lag_gain * (acting - self.position)
        return self.position, hop

    def requeue(self, acting: np.ndarray | None, in_flight: deque) -> None:
        """Commands re-paired under another latency: the one acting now and those on their way."""
        if acting is not None:
            self.acting = acting
        self.in_flight = in_flight

    def rescale(self, ratio: float) -> None:
        """Every set-point in new cycles, ``ratio`` of them per old one."""
        self.base = self.base * ratio
        self.last_command = self.last_command * ratio
        self.acting = self.acting * ratio
        self.position = self.position * ratio
        for entry in self.in_flight:
            entry[1] = entry[1] * ratio


def excursion(p: TrackerParams, n: int, tick: int) -> np.ndarray:
    """The tracking excursion's direction at ``tick`` (N,): ``one`` stage at a time, alternating
    in sign; ``all``: every stage at once, the signs of a row of a Hadamard matrix (the rows
    cycle, so every stage's sign is seen against every other's)."""
    if p.hold_pattern == "one":
        out = np.zeros(n)
        out[tick % n] = 1.0 if (tick // n) % 2 == 0 else -1.0
        return out
    size = 1 << max(n, 1).bit_length()  # a Hadamard order > n (Sylvester)
    return _hadamard_row(n, tick % size)


@functools.lru_cache(maxsize=256)
def _hadamard_row(n: int, row: int) -> np.ndarray:
    """Row ``row`` of a Sylvester Hadamard matrix over columns 1..n, over sqrt(n) (read-only)."""
    cols = np.arange(1, n + 1)  # skip the all-ones column
    bits = np.array([bin(row & c).count("1") & 1 for c in cols])
    out = (1.0 - 2.0 * bits) / np.sqrt(n)
    out.flags.writeable = False
    return out


def hold_dither(p: TrackerParams, noise_var: float, drift: np.ndarray) -> float:
    """The tracking excursion's length: ``hold_dither_cycles``, larger on a noisy detector (a
    reading near the optimum is quadratic in the error, so the excursion must lift its signal
    above the noise: ``noisy_dither_factor`` sqrt(sigma) cycles) and on a fast drift. With the
    all-stage pattern each stage moves by length / sqrt(N) in every reading instead of the whole
    length in one reading of N: the same information per reading at the same cost in power."""
    noise = noise_var**0.5
    fast = p.drift_dither_gain * float(np.max(np.abs(drift)))
    return max(p.hold_dither_cycles, p.noisy_dither_factor * noise**0.5, fast)
