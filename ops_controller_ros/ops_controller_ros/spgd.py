"""SPGD-PID: stochastic parallel gradient descent on the measured power, with a PID stage.

The classic controller of coherent beam combining (the paper's introduction). One iteration:

1. draw a random sign vector s in {-1, +1}^N and perturb all delays at once, two-sided:
   measure J+ = P(u + a s) and J- = P(u - a s);
2. estimate the gradient g = (J+ - J-) / (2 a) * s  (power per fs);
3. the error e_k = gain * g (fs) drives a PID stage, Δ = kp e_k + ki Σe + kd (e_k - e_{k-1}),
   optionally smoothed by momentum (v = m v + Δ), clipped to ``max_update_fs``; u += v.

Two departures from the paper's SPGD-PID, both on by default and both measured (docs/results.md,
"SPGD-PID: the user's first run"); :data:`PAPER` switches both off (the benchmark's baseline):

Normalized gradient (``normalized``): the estimate is divided by the measured power (the gradient
of log P). Far from the peak the landscape is flat and a fixed gain crawls for hundreds of
readings; with the normalization a step has the same size at any power, and at the peak
(P ~ 1) nothing changes.

Restarts (``recovery="restart"``; ``"none"`` never restarts): SPGD is a
local method, and from the initial errors of medium and hard modes it often climbs a side peak of
the periodic landscape (P_N/P_max ~ 0.33 at N = 3, every stage half a cycle off) and stays there; no
single-stage move leads off such a peak. When P_N/P_max is below ``restart_below`` and has been flat
(within ``restart_flat`` of its level) over the last ``restart_after`` iterations since the start
or the last restart -- a plateau, not a slow climb -- the controller walks every
set-point to a random offset within +- ``restart_range_fs`` / 2 (one optical cycle wide: every
delay's landscape repeats with the optical period), in steps of ``restart_step_fs`` (below the
actuator's largest step; readings on the way are not used), and SPGD starts again there. The best
plateau seen is remembered: a restart leaves from it. ``restart_below`` (0.6) sits above every
side peak: none exceeds 1/3 behind the polarizer or 1/2 with both ports (N = 2-6, gradient
ascent from random starts: ``ops-bench side-peaks`` at commit 367a582). A plateau above it is
the main peak, lagging hard mode's drift; with 0.9 SPGD restarted such plateaus and threw the
lock away (hard, N = 5: 0.357 -> 0.418 with 0.6, 2,000 episodes; docs/results/spgd/index.md).

The class is a state machine with no notion of time or transport: ``command()`` gives
the set-points to apply next, ``observe(power)`` the reading they produced. The ROS node and the
in-process evaluation both drive it the same way.

Latency (``latency`` > 0, the rig's ``latency_steps``): a command acts that many steps
after the reading it answered, so the reading after a command was made by the one ``latency``
commands before. SPGD then keeps a perturbation in flight every step, files each reading under
the perturbation that made it (J+ or J- of which pair), and updates the set-points when a
pair's second reading comes: the same iteration rate, each gradient ``latency`` steps old. A
climb then shows in the readings ``latency`` steps late and zig-zags on the stale gradients, so
the plateau a restart waits for is judged over ``restart_after + restart_after_per_latency *
latency`` iterations (rounded up): with the plain window, latency 4 restarted climbs that were
still going and lost 0.07 / 0.12 of P_N/P_max in medium / hard (1,000 episodes on tuning seeds,
docs/results/spgd/index.md).
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

from .param_fields import check, declare

#: ``SpgdParams.recovery``: "restart" leaves a side peak by random restarts; "none": the paper's.
RECOVERIES = ("restart", "none")


@dataclass(frozen=True)
class SpgdParams:
    """SPGD-PID's parameters, each declared once with its meaning and range: the dataclass
    checks itself against them, and the ``spgd`` node declares each field as a parameter with
    the same default, description and range (``spgd_node.PARAMS``,
    :func:`~ops_controller_ros.param_fields.param_specs`)."""

    gain: float = declare(
        0.05,
        "SPGD gain: fs^2 per unit of normalized power (e = gain * dP/ddelay)",
        0.0,
        1e6,
        low_open=True,
    )
    perturbation_fs: float = declare(
        0.03,
        "dither amplitude per stage, fs (about 1 % of a 1030 nm cycle)",
        0.0,
        1e3,
        low_open=True,
    )
    kp: float = declare(1.0, "PID proportional gain on the SPGD update", -1e6, 1e6)
    ki: float = declare(0.0, "PID integral gain", -1e6, 1e6)
    kd: float = declare(0.0, "PID derivative gain", -1e6, 1e6)
    momentum: float = declare(0.0, "momentum of the update (below 1)", 0.0, 0.999)
    max_update_fs: float = declare(
        0.5, "largest set-point change per iteration, fs", 0.0, 1e3, low_open=True
    )
    integral_limit_fs: float = declare(
        5.0, "anti-windup bound of the PID's integral term, fs", 0.0, 1e3
    )
    normalized: bool = declare(True, "divide the gradient by the power (false: the paper's SPGD)")
    normalize_floor: float = declare(
        0.02, "smallest power the gradient is divided by", 0.0, 1.0, low_open=True
    )
    recovery: str = declare(
        "restart",
        "restart: leave a side peak by random restarts; none: the paper's",
        choices=RECOVERIES,
    )
    # restart when P_N/P_max is still below this (above every side peak: module docstring) ...
    restart_below: float = declare(
        0.6, "restart while P_N/P_max is below this (above every side peak) ...", 0.0, 1.0
    )
    restart_after: int = declare(
        10, "... and flat over this many iterations since the last", 1, 100000
    )
    restart_flat: float = declare(
        0.1, "... within this fraction of its level (a plateau, not a climb)", 0.0, 1.0
    )
    restart_after_per_latency: float = declare(
        2.5,
        "... a window longer by this many iterations per step of the rig's latency",
        0.0,
        1e3,
    )
    restart_range_fs: float = declare(
        3.6, "width of a restart's random offset, fs (one 1030 nm cycle: 3.44 fs)", 0.0, 1e3
    )
    restart_step_fs: float = declare(
        0.06,
        "set-point change per reading on the way to a restart, fs",
        0.0,
        1e3,
        low_open=True,
    )

    def __post_init__(self):
        check(self)

    def to_dict(self) -> dict:
        return asdict(self)


#: The paper's SPGD-PID: no normalization, no restarts (Table 1's baseline; stalls in medium/hard).
PAPER = {"normalized": False, "recovery": "none"}


class SpgdPid:
    """Two-sided SPGD with a PID stage on the update (see module docstring)."""

    def __init__(
        self,
        stage: int,
        params: SpgdParams | None = None,
        setpoints_fs=None,
        seed=None,
        latency: int = 0,
    ):
        self.stage = int(stage)
        self.params = params or SpgdParams()
        if int(latency) < 0:
            raise ValueError(f"latency must be >= 0 steps (got {latency})")
        self.latency = int(latency)
        p = self.params
        self._plateau_window = p.restart_after + int(
            np.ceil(p.restart_after_per_latency * self.latency - 1e-9)
        )
        self._rng = np.random.default_rng(seed)
        self.reset(np.zeros(self.stage) if setpoints_fs is None else setpoints_fs)

    def reset(self, setpoints_fs) -> None:
        """Start again from ``setpoints_fs`` (e.g. after the simulator restarted)."""
        u = np.asarray(setpoints_fs, dtype=np.float64).reshape(self.stage)
        self.setpoints_fs = u.copy()
        self._velocity = np.zeros(self.stage)
        self._integral = np.zeros(self.stage)
        self._last_error = np.zeros(self.stage)
        self._signs = self._rng.choice((-1.0, 1.0), size=self.stage)
        self._phase = 0  # 0: waiting for J+, 1: waiting for J-
        self._j_plus = 0.0
        self.iterations = 0
        self.restarts = 0
        self.last_power = float("nan")
        self._walk = []  # set-points still to visit on the way to a restart point
        self._since_restart = 0
        self._recent = []  # P_N/P_max of each iteration since the last (re)start
        self._best = (-np.inf, u.copy())  # (plateau power, its set-points)
        # latency > 0: what each command in flight was ((epoch, pair, +1 / -1 / 0 for a walk
        # step), oldest first), the command given and not yet read, the pairs' J+
        self._in_flight: deque = deque()
        self._given = None
        self._epoch = 0  # a restart starts a new one: perturbations of the old are not used
        self._pair = 0
        self._pairs: dict = {}  # (epoch, pair) -> [signs, set-points, J+ or None]

    def move_setpoints(self, delta_fs) -> None:
        """Move the set-points by ``delta_fs`` (whole optical periods: the loop node keeps them
        inside a rig's range, :mod:`ops_controller_ros.setpoint_range`). The interference is
        the same there, so everything built on the set-points follows: the dither pair under
        way, a walk to a restart point, the best plateau a restart leaves from, the commands in
        flight under a latency. The PID state (velocity, integral) is kept."""
        d = np.asarray(delta_fs, dtype=np.float64).reshape(self.stage)
        self.setpoints_fs = self.setpoints_fs + d
        self._walk = [w + d for w in self._walk]
        self._best = (self._best[0], self._best[1] + d)
        if self._given is not None:
            self._given = self._given + d
        for pair in self._pairs.values():
            pair[1] = pair[1] + d

    # ------------------------------------------------------------------ restarts
    @property
    def restarting(self) -> bool:
        """True while walking to a restart point (the readings are not used)."""
        return bool(self._walk)

    def _restart(self) -> None:
        p = self.params
        self._epoch += 1
        self._pairs.clear()  # perturbations still in flight belong to the old epoch: not used
        if self.last_power > self._best[0]:
            self._best = (self.last_power, self.setpoints_fs.copy())
        start = self._best[1]
        target = start + self._rng.uniform(-0.5, 0.5, self.stage) * p.restart_range_fs
        n = max(int(np.ceil(np.max(np.abs(target - self.setpoints_fs)) / p.restart_step_fs)), 1)
        here = self.setpoints_fs
        self._walk = [here + (target - here) * k / n for k in range(1, n + 1)]
        self.setpoints_fs = target
        self._velocity = np.zeros(self.stage)
        self._integral = np.zeros(self.stage)
        self._last_error = np.zeros(self.stage)
        self._phase = 0
        self._since_restart = 0
        self._recent = []
        self.restarts += 1

    def command(self) -> np.ndarray:
        """Set-points (fs) to apply now: the scan's next point, else u + a s, then u - a s."""
        if self.latency:
            return self._command_in_flight()
        if self._walk:
            return self._walk[0]
        sign = 1.0 if self._phase == 0 else -1.0
        return self.setpoints_fs + sign * self.params.perturbation_fs * self._signs

    def observe(
        self, power: float, pulse_energies=None, steps: int = 1, command_age: int | None = None
    ) -> None:
        """The power measured with the last ``command()``; every second reading updates u.

        SPGD uses the power only; ``pulse_energies``, ``steps`` and ``command_age`` are accepted
        for the common
        interface of :mod:`ops_controller_ros.controllers` (a gradient step has no model of
        time)."""
        if self.latency:
            self._observe_in_flight(float(power))
            return
        if self._walk:
            self._walk.pop(0)
            return
        if self._phase == 0:
            self._j_plus = float(power)
            self._phase = 1
            if self.iterations == 0:  # no J+/J- pair yet: the reading itself
                self.last_power = self._j_plus
            return
        self._update(self._j_plus, float(power), self._signs)
        self._signs = self._rng.choice((-1.0, 1.0), size=self.stage)
        self._phase = 0
        self._maybe_restart()

    def _update(self, j_plus: float, j_minus: float, signs: np.ndarray) -> None:
        """One iteration from a pair's two readings: gradient, PID, set-points."""
        p = self.params
        self.last_power = 0.5 * (j_plus + j_minus)
        gradient = (j_plus - j_minus) / (2.0 * p.perturbation_fs) * signs
        if p.normalized:  # the gradient of log P: the same step size at any power
            gradient = gradient / max(self.last_power, p.normalize_floor)
        error = p.gain * gradient
        self._integral = np.clip(self._integral + error, -p.integral_limit_fs, p.integral_limit_fs)
        update = p.kp * error + p.ki * self._integral + p.kd * (error - self._last_error)
        self._last_error = error
        self._velocity = p.momentum * self._velocity + update
        self._velocity = np.clip(self._velocity, -p.max_update_fs, p.max_update_fs)
        self.setpoints_fs = self.setpoints_fs + self._velocity
        self.iterations += 1
        self._since_restart += 1
        self._recent.append(self.last_power)

    def _maybe_restart(self) -> None:
        p = self.params
        if (
            p.recovery == "restart"
            and self._since_restart >= self._plateau_window
            and self.last_power < p.restart_below
            and _flat(self._recent, self._plateau_window, p.restart_flat)
        ):
            self._restart()  # stalled on a side peak: look elsewhere

    # ------------------------------------------------------------------ with latency
    def _command_in_flight(self) -> np.ndarray:
        if self._given is not None:  # asked again before its reading (a node's re-send)
            return self._given
        if self._walk:
            command, tag = self._walk.pop(0), (self._epoch, None, 0)
        else:
            key = (self._epoch, self._pair)
            if key not in self._pairs:  # both halves of a pair around the same set-points
                signs = self._rng.choice((-1.0, 1.0), size=self.stage)
                self._pairs[key] = [signs, self.setpoints_fs.copy(), None]
            signs, base, _ = self._pairs[key]
            sign = 1.0 if self._phase == 0 else -1.0
            command = base + sign * self.params.perturbation_fs * signs
            tag = (*key, sign)
            self._pair += self._phase  # the pair's second command: the next one starts anew
            self._phase ^= 1
        self._in_flight.append(tag)
        self._given = command
        return command

    def _observe_in_flight(self, power: float) -> None:
        self._given = None
        if len(self._in_flight) <= self.latency:
            return  # made by the set-points before the first command
        epoch, pair, sign = self._in_flight.popleft()
        if self.iterations == 0:
            self.last_power = power  # no J+/J- pair yet: the reading itself
        if sign == 0 or epoch != self._epoch:
            return  # a walk step, or a perturbation from before a restart
        if sign > 0:
            self._pairs[(epoch, pair)][2] = power
            return
        signs, _, j_plus = self._pairs.pop((epoch, pair))
        if j_plus is not None:
            self._update(j_plus, power, signs)
            self._maybe_restart()
        if self._walk:  # restarted: the next commands walk
            self._phase = 0


def _flat(powers: list[float], window: int, tolerance: float) -> bool:
    """True when the last ``window`` powers spread by less than ``tolerance`` times their top
    (a plateau, not a climb)."""
    last = powers[-window:]
    top = max(last)
    return top - min(last) <= tolerance * top
