"""LoopStatus: locked / searching / starved judged from the readings, not the controller."""

from ops_controller_ros.loop_status import LOCKED, SEARCHING, STARVED, LoopStatus


def test_starved_before_any_reading_and_after_a_silence():
    status = LoopStatus(lock_threshold=0.9, starved_after_s=1.0)
    assert status.judge(0.0) == STARVED and status.explain() == "no reading yet"
    status.observe(0.5, now=10.0)
    assert status.judge(10.5) == SEARCHING
    assert status.judge(11.01) == STARVED


def test_locked_only_when_every_one_of_the_last_ten_readings_is_above_the_threshold():
    status = LoopStatus(lock_threshold=0.9, starved_after_s=1.0)
    t = 0.0
    for _ in range(9):
        t += 0.01
        status.observe(0.99, t)
    assert status.judge(t) == SEARCHING  # nine readings are not ten
    status.observe(0.99, t + 0.01)
    assert status.judge(t + 0.01) == LOCKED


def test_a_lock_is_left_only_after_several_low_readings_in_a_row():
    """Hysteresis: without it the log flipped locked -> searching several times a second."""
    status = LoopStatus(lock_threshold=0.9, starved_after_s=1.0, unlock_after=3)
    t = 0.0
    for _ in range(10):
        t += 0.01
        status.observe(0.99, t)
    assert status.update(t) == LOCKED
    for power in (0.5, 0.95, 0.4, 0.3):  # two low, one good, two low: never three in a row
        t += 0.01
        status.observe(power, t)
        assert status.update(t) is None
    t += 0.01
    status.observe(0.2, t)  # the third low reading in a row
    assert status.update(t) == SEARCHING
    assert "3 readings in a row below 0.9" in status.explain()
    status.observe(0.99, t + 0.01)  # back up: locked again only after ten good readings
    assert status.judge(t + 0.01) == SEARCHING


def test_update_reports_changes_once():
    status = LoopStatus(lock_threshold=0.9, starved_after_s=1.0, window=2)
    assert status.update(0.0) is None  # starved from the start: no change
    status.observe(0.95, 0.1)
    assert status.update(0.1) == SEARCHING
    status.observe(0.95, 0.2)
    assert status.update(0.2) == LOCKED
    assert status.update(0.3) is None
    assert status.update(5.0) == STARVED
    assert "no reading for more than 1 s" in status.explain()
