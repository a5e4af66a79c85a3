"""The drift remembered under a told vibration (tracker/drift_memory.py), on lines of estimates
made here: the slope of a long span, a stage let go of alone where it leaves its line, every
stage where the whole drift reverses, and not for a walk that takes every stage off at once."""

from __future__ import annotations

import numpy as np
import pytest
from ops_controller_ros.tracker.drift_memory import DriftMemory, bent_line_slope

TIGHT, AFTER = 2e-5, 1e-4


def _memory(span=1200, least=200, window=20, turn=0.05, after=AFTER):
    return DriftMemory(span, least, window, TIGHT, turn, after)


def _line(rng, steps, drift, walk=0.001, noise=0.004):
    """Estimates of a drift with a random walk, each off by ``noise`` (K, N)."""
    path = np.cumsum(drift + walk * rng.standard_normal((steps, drift.size)), axis=0)
    return path + noise * rng.standard_normal(path.shape)


def _filled(memory, rng, drift, steps=600):
    """``memory`` after ``steps`` estimates of ``drift``; the last estimate."""
    xs = _line(rng, steps, drift)
    for step, x in enumerate(xs):
        memory.take(step, x, drift)
    assert memory.held.all() and memory.turns == 0
    return xs[-1]


def test_the_drift_memory_remembers_the_slope_of_a_long_span():
    rng = np.random.default_rng(0)
    drift = np.array([0.001, -0.0008, 0.0012, 0.0005, -0.001])
    memory, error = _memory(after=0.0), []
    for step, x in enumerate(_line(rng, 1200, drift)):
        carried = memory.take(step, x, drift + 5e-4)  # a window's own drift, well off
        if step < 200:
            assert memory.slope is None and np.array_equal(carried, drift + 5e-4)
            assert not memory.active
        else:
            held = memory.held
            assert np.array_equal(carried[held], memory.slope[held])
            error.append(np.abs(memory.slope - drift)[held].max(initial=0.0))
    # a walk of 0.001 a step over a minute and more: the slope to about 1e-4 (not the 5e-4 of
    # the window's); no stage let go of where nothing turned
    assert memory.turns == 0 and memory.stage_turns <= 2
    assert max(error[-200:]) < 1.5e-4, max(error[-200:])


def test_the_running_sums_give_the_least_squares_slope():
    rng = np.random.default_rng(1)
    memory = _memory(span=300, least=50)
    t = np.arange(0, 5000, 2)  # a fit every other step: the span holds 151 estimates
    xs = _line(rng, t.size, np.array([0.002, -0.001, 0.0, 0.003, 0.001]), walk=0.0)
    xs += 1000.0  # a long run's estimates are far from zero
    for step, x in zip(t, xs, strict=True):
        memory.take(int(step), x, np.zeros(5))
    kept = t >= t[-1] - 300
    expected = np.polyfit(t[kept], xs[kept], 1)[0]
    assert np.allclose(memory.slope, expected, rtol=1e-9, atol=1e-12)


def test_the_whole_drift_reversing_lets_go_of_every_stage():
    rng = np.random.default_rng(4)
    drift = np.array([0.001, 0.0008, 0.0012, 0.0006, 0.001])
    memory = _memory()
    x = _filled(memory, rng, drift)
    held = memory.slope.copy()
    for step in range(600, 640):
        x = x - drift + 0.001 * rng.standard_normal(5)
        carried = memory.take(step, x, drift)
        if memory.turns:
            break
    # let go within a window, every stage at once, on with the slopes let go of turned round
    # (one share of them for all), the looser prior, no faster than twice the fastest slope
    assert memory.turns == 1 and memory.stage_turns == 0 and memory.slope is None, step
    assert step - 600 <= 20
    share = carried / held
    assert np.allclose(share, share[0], rtol=0.02) and -2.0 <= share[0] < -0.3, share
    assert np.array_equal(memory.priors(7e-4), np.full(5, AFTER))
    assert np.allclose(memory.limit, 2.0 * held.max(), rtol=0.02)
    # the fits' own drift until the memory holds a slope again, within that speed
    assert np.array_equal(memory.take(step + 1, x - drift, -drift), -drift)
    fast = memory.take(step + 2, x - 2 * drift, -10.0 * drift)  # a knot fit's few readings
    assert np.array_equal(np.abs(fast), memory.limit)
    for later in range(step + 3, step + 260):
        x = x - drift + 0.001 * rng.standard_normal(5)
        carried = memory.take(later, x, -drift)
    assert memory.held.all() and memory.limit is None
    assert np.array_equal(memory.priors(7e-4), np.full(5, TIGHT))
    assert np.array_equal(carried, memory.slope)
    assert np.abs(memory.slope + drift).max() < 2e-4


def test_one_stage_off_its_line_is_let_go_of_alone_on_its_slope():
    rng = np.random.default_rng(4)
    drift = np.full(5, 0.003)
    memory = _memory()
    x = _filled(memory, rng, drift)
    held = memory.slope.copy()
    turned = drift.copy()
    turned[2] *= -1.0  # one line's drift reverses
    for step in range(600, 640):
        x = x + turned + 0.001 * rng.standard_normal(5)
        carried = memory.take(step, x, drift)
        if memory.stage_turns:
            break
    # stage 2 alone, on from its slope let go of (not the window's, which carries whatever
    # took it off the line), under the looser prior; the others keep theirs
    assert memory.stage_turns == 1 and memory.turns == 0, step
    assert np.array_equal(memory.held, [True, True, False, True, True])
    assert carried[2] == held[2] or abs(carried[2] - held[2]) < 1e-4
    assert np.array_equal(memory.priors(7e-4), [TIGHT, TIGHT, AFTER, TIGHT, TIGHT])
    assert np.isinf(memory.limit[[0, 1, 3, 4]]).all() and memory.limit[2] > 0.0
    # then the stage's fits' own drift (within the limit) until its memory fills again
    own = memory.take(step + 1, x + turned, turned)
    assert own[2] == turned[2] and np.array_equal(own[[0, 1, 3, 4]], memory.slope[[0, 1, 3, 4]])
    for later in range(step + 2, step + 260):
        x = x + turned + 0.001 * rng.standard_normal(5)
        carried = memory.take(later, x, turned)
    assert memory.held.all() and memory.limit is None
    assert abs(memory.slope[2] - turned[2]) < 2e-4


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_walk_that_takes_every_stage_off_at_once_is_no_reversal(seed):
    """A walk of 0.003 a step and estimates off by 0.008 (the ``lab`` rig's at 10 Hz, about)
    take every stage off its line along the reversal now and then; the bent line tells most of
    these from a turn."""

    class Counted(DriftMemory):
        displaced = 0

        def _reversal(self, off, slope, filled):
            s = np.where(filled, slope, 0.0)
            if -float(off @ s) / float(np.linalg.norm(s)) > self.turn:
                self.displaced += 1
            return super()._reversal(off, slope, filled)

    rng = np.random.default_rng(seed)
    drift = np.full(5, 0.0015)
    memory = Counted(1200, 200, 20, TIGHT, 0.05, AFTER)
    for step, x in enumerate(_line(rng, 6000, drift, walk=0.003, noise=0.008)):
        memory.take(step, x, drift)
    # measured: displaced 9, 5, 9 times, let go of 1, 0, 1 times
    assert memory.displaced >= 4
    assert memory.turns <= memory.displaced // 4, (memory.turns, memory.displaced)


def test_without_a_prior_after_a_turn_the_fits_own_drift_goes_on():
    rng = np.random.default_rng(4)
    drift = np.full(5, 0.001)
    memory = _memory(after=0.0)
    x = _filled(memory, rng, drift)
    for step in range(600, 640):
        x = x - drift + 0.001 * rng.standard_normal(5)
        memory.take(step, x, drift)
        if memory.turns:
            break
    assert memory.turns == 1 and memory.limit is None and not memory.active
    assert np.array_equal(memory.take(step + 1, x - drift, -10 * drift), -10 * drift)


def test_the_bent_line_finds_the_slope_after_the_turn():
    t = np.arange(40, dtype=np.float64)
    before = np.array([0.002, -0.001])
    after = np.array([-0.0015, 0.0005])
    bend = 28.0
    x = np.where((t < bend)[:, None], np.outer(t - bend, before), np.outer(t - bend, after))
    assert np.allclose(bent_line_slope(t, x, before, 20), after)


def test_a_knot_taken_lets_go_of_every_stage_on_the_knots_drift():
    """A knot fit found the drift's slope changed: a held slope carried on past it would undo
    the knot's drift and leave its path behind (on the `lab` rig, the deepest dips at a turn)."""
    from ops_controller_ros.tracker.tracking import Lock

    rng = np.random.default_rng(5)
    drift = np.full(5, 0.001)
    lock = Lock(5, memory=_memory())
    x = _filled(lock.memory, rng, drift)
    lock.estimate = x
    knot = np.array([-0.001, -0.0012, 0.0, -0.01, -0.0009])  # one far too fast
    lock.drift = knot.copy()
    lock.let_go()
    memory = lock.memory
    assert memory.knots == 1 and memory.turns == 0 and not memory.held.any()
    limit = memory.limit[0]
    assert limit == pytest.approx(2.0 * 0.001, rel=0.1)
    assert np.array_equal(lock.drift, np.clip(knot, -limit, limit))
    assert np.array_equal(memory.priors(7e-4), np.full(5, AFTER))
    # the fits' own drift (within the limit) until the memory fills again
    assert np.array_equal(memory.take(600, x - drift, -drift), -drift)
    assert lock.remembered() is memory


def test_a_knot_without_a_held_slope_changes_nothing():
    memory = _memory()
    assert np.array_equal(memory.knotted(np.full(5, 0.3)), np.full(5, 0.3))
    assert memory.knots == 0
