"""Set-points kept inside a rig's range by whole optical periods (docs/rig.md, "Known limits").

A rig refuses a set-point outside its delay line's range (the channel's voltage limits through
its calibration, ``RigModel.setpoint_range_fs``), and the thermal drift carries a lock towards a
limit: a controller that follows it reaches the limit within minutes, and every later command is
refused. The interference repeats with the optical period in each delay (the pulse envelope, a
thousand times wider, hardly changes over a few cycles), so a set-point moved by whole periods
gives the same stack: a set-point that comes within ``margin_cycles`` of a limit is moved inwards
by whole periods (:func:`inward_periods`), and the controller's state follows the move.

One rule for every controller: the tracker moves its own set-points by it
(``tracker/period.py``, one stage per reading, in its model's cycles), and the loop node
(:mod:`.loop_node`) moves the commands of a controller that does not (SPGD, a learned policy)
with :class:`RangeKeeper`, telling the controller (``move_setpoints``). Pure numpy: no rclpy.
"""

from __future__ import annotations

import math

import numpy as np

#: A set-point this near (optical cycles) to its line's limit moves whole cycles inwards.
MARGIN_CYCLES = 2.0


def _range(low_fs, high_fs, n: int) -> tuple[np.ndarray, np.ndarray]:
    low = np.broadcast_to(np.asarray(low_fs, dtype=np.float64), (n,))
    high = np.broadcast_to(np.asarray(high_fs, dtype=np.float64), (n,))
    return low, high


def movable(low_fs, high_fs, period_fs: float, margin_cycles: float = MARGIN_CYCLES) -> np.ndarray:
    """Per stage, whether its range is wide enough for the moves (at least ``2 margin + 1``
    periods: a set-point a whole number of periods from the middle then keeps the margin)."""
    low, high = (np.atleast_1d(np.asarray(r, dtype=np.float64)) for r in (low_fs, high_fs))
    return high - low >= (2.0 * margin_cycles + 1.0) * period_fs


def inward_periods(
    setpoints_fs,
    low_fs,
    high_fs,
    period_fs: float,
    margin_cycles: float = MARGIN_CYCLES,
    most_periods: int | None = None,
) -> np.ndarray:
    """Whole periods (ints, one per stage; the sign is the direction) to move each set-point.

    0 where the set-point keeps ``margin_cycles`` periods from both limits, or where the range
    is narrower than ``2 margin + 1`` periods (:func:`movable`: no whole-period move keeps it
    there). Else towards the middle of the range, to the whole period nearest to it, but at most
    ``most_periods`` (the periods a line moves in one reading at its slew limit; at least one;
    None: any number). Without that cap the moved set-point is within half a period of the
    middle, hence within ``[low + margin, high - margin]``."""
    x = np.asarray(setpoints_fs, dtype=np.float64).reshape(-1)
    low, high = _range(low_fs, high_fs, x.size)
    period = float(period_fs)
    if not period > 0.0:
        raise ValueError(f"period_fs must be > 0 (got {period_fs!r})")
    margin = float(margin_cycles) * period
    near = (x - low < margin) | (high - x < margin)
    due = near & movable(low, high, period, margin_cycles)
    periods = np.rint((0.5 * (low + high) - x) / period).astype(np.int64)
    if most_periods is not None:
        most = max(1, int(most_periods))
        periods = np.clip(periods, -most, most)
    return np.where(due, periods, 0)


def move_inwards(
    setpoints_fs,
    low_fs,
    high_fs,
    period_fs: float,
    margin_cycles: float = MARGIN_CYCLES,
    most_periods: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(the set-points moved, the whole periods each moved): :func:`inward_periods` applied."""
    x = np.asarray(setpoints_fs, dtype=np.float64).reshape(-1)
    periods = inward_periods(x, low_fs, high_fs, period_fs, margin_cycles, most_periods)
    return x + periods * float(period_fs), periods


def periods_per_reading(reach_fs: float | None, period_fs: float) -> int | None:
    """The whole periods a line moves in one reading at its slew limit (``reach_fs``, the rig
    file's ``reach_fs_per_reading``), at least one; None where it is not known (any number)."""
    if reach_fs is None:
        return None
    return max(1, math.floor(float(reach_fs) / float(period_fs)))


class RangeKeeper:
    """Keeps a controller's commands inside ``(low_fs, high_fs)`` (the loop node's, for a
    controller that does not keep them itself).

    :meth:`keep` moves a command that comes within ``margin_cycles`` of a limit by whole periods
    inwards (:func:`inward_periods`, at most what a line makes in one reading, ``reach_fs``) and
    tells the controller (``ctrl.move_setpoints(delta_fs)``: its set-points and the state built
    on them follow); and clips whatever is still out (a range too narrow for the moves, a move
    capped by the slew limit), so that no command beyond the range goes out."""

    def __init__(
        self,
        low_fs,
        high_fs,
        period_fs: float,
        margin_cycles: float = MARGIN_CYCLES,
        reach_fs: float | None = None,
    ):
        self.low_fs = np.atleast_1d(np.asarray(low_fs, dtype=np.float64)).copy()
        self.high_fs = np.atleast_1d(np.asarray(high_fs, dtype=np.float64)).copy()
        if self.low_fs.shape != self.high_fs.shape or np.any(self.low_fs > self.high_fs):
            raise ValueError("the range needs low <= high, one pair per stage")
        self.period_fs = float(period_fs)
        self.margin_cycles = float(margin_cycles)
        self.most_periods = periods_per_reading(reach_fs, self.period_fs)
        # a command inside both margins needs no move and no clip (the common case, each step)
        margin = self.margin_cycles * self.period_fs
        self._clear_low, self._clear_high = self.low_fs + margin, self.high_fs - margin
        self.moves = 0  # set-points moved (one per stage and move)
        self.clipped = 0  # commands clipped into the range
        self.last_move = None  # the whole periods of the last move, per stage

    @property
    def stage(self) -> int:
        return self.low_fs.size

    def narrow_stages(self) -> list[int]:
        """The stages whose range is too narrow for whole-period moves (only clipped)."""
        ok = movable(self.low_fs, self.high_fs, self.period_fs, self.margin_cycles)
        return [int(j) for j in np.flatnonzero(~ok)]

    def describe(self) -> str:
        """One line for the log: the range per stage, the margin and the moves' cap."""
        ranges = ", ".join(
            f"[{a:.1f}, {b:.1f}]" for a, b in zip(self.low_fs, self.high_fs, strict=True)
        )
        cap = (
            "any number of periods per move"
            if self.most_periods is None
            else f"at most {self.most_periods} per move (the slew limit)"
        )
        narrow = self.narrow_stages()
        note = f"; stages {narrow} too narrow for moves: only clipped" if narrow else ""
        return (
            f"set-point range in force, fs: {ranges}; a set-point within "
            f"{self.margin_cycles:g} cycles of a limit moves whole periods "
            f"({self.period_fs:.3f} fs) inwards, {cap}{note}"
        )

    def keep(self, ctrl, command_fs) -> np.ndarray:
        """The command to send instead of ``command_fs``: moved and clipped as the class says;
        a move is also made on ``ctrl`` (``move_setpoints``), so its next commands follow. A
        controller without ``move_setpoints`` is not moved: its commands are only clipped."""
        command = np.asarray(command_fs, dtype=np.float64).reshape(-1)
        if command.size != self.stage:
            raise ValueError(f"a command of {command.size} set-points; the range has {self.stage}")
        if np.all(command >= self._clear_low) and np.all(command <= self._clear_high):
            return command
        if getattr(ctrl, "move_setpoints", None) is None:
            return self.clip(command)
        periods = inward_periods(
            command,
            self.low_fs,
            self.high_fs,
            self.period_fs,
            self.margin_cycles,
            self.most_periods,
        )
        if periods.any():
            delta = periods * self.period_fs
            ctrl.move_setpoints(delta)
            command = command + delta
            self.moves += int(np.count_nonzero(periods))
            self.last_move = periods
        return self.clip(command)

    def clip(self, command_fs) -> np.ndarray:
        """``command_fs`` clipped into the range (counted when that changed it)."""
        command = np.asarray(command_fs, dtype=np.float64).reshape(-1)
        inside = np.clip(command, self.low_fs, self.high_fs)
        if not np.array_equal(inside, command):
            self.clipped += 1
        return inside
