"""ops-bench soak on a few simulated seconds: a run stopped mid-way resumes from its checkpoint to
the very figures of a run never stopped; other settings are refused; the page and figure come."""

from __future__ import annotations

import json

import pytest
from ops_experiments.timed_loop import CappedLoop

from ops_bench import soak

# The tracker at 10 Hz on the lab rig (no vibration, so it locks at once), its compute fixed so
# that two runs take the same steps; 12 s in blocks of 2 s, a checkpoint after each block.
ARGS = ["--rate", "10", "--vibration", "none", "--compute-ms", "1", "--block-s", "2",
        "--checkpoint-every", "2", "--seed", "11", "--no-progress"]  # fmt: skip
HOURS = str(12 / 3600)


def run(tmp_path, name, *extra):
    out = tmp_path / name
    argv = [*ARGS, "--hours", HOURS, "--out", str(out), "--page", str(out / "page"),
            "--figure", str(out / "soak.png"), *extra]  # fmt: skip
    return soak.main(argv), out


def figures(out):
    result = json.loads((out / "summary.json").read_text())
    for key in ("wall_s", "commands", "compute_ms_median", "compute_ms_p99"):
        result.pop(key)  # the time it took: measured, not the run's figures
    state = soak.load_state(out / "state.pkl")
    return result, state["blocks"]


def test_a_stopped_soak_resumes_to_the_same_result(tmp_path, monkeypatch):
    code, whole = run(tmp_path, "whole")
    assert code == 0
    calls = {"n": 0}
    plain = CappedLoop.run

    def interrupted(self, steps):
        calls["n"] += 1
        if calls["n"] == 4:  # killed in the fourth block, after three checkpoints
            raise KeyboardInterrupt
        return plain(self, steps)

    monkeypatch.setattr(CappedLoop, "run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path, "stopped")
    monkeypatch.setattr(CappedLoop, "run", plain)
    assert soak.load_state(tmp_path / "stopped" / "state.pkl")["loop"].step == 60
    code, stopped = run(tmp_path, "stopped")
    assert code == 0
    want, want_blocks = figures(whole)
    got, got_blocks = figures(stopped)
    assert got == want
    assert got_blocks == want_blocks and len(got_blocks["p_mean"]) == 6
    assert want["steps"] == 120 and want["first_lock_step"] is not None


def test_the_soak_writes_its_summary_page_and_figure(tmp_path):
    code, out = run(tmp_path, "docs")
    assert code == 0
    result = json.loads((out / "summary.json").read_text())
    assert set(result["goals"]) == {
        "power_rms_pct <= 1.5",
        "readings >= 0.95: >= 99.9 %",
        "no lock lost",
    }
    page = (out / "page" / "index.md").read_text()
    assert "ops-bench soak" in page and "| locks lost" in page
    assert (out / "soak.png").stat().st_size > 0
    assert len((out / "page" / "blocks.csv").read_text().splitlines()) == 1 + 6


def test_other_settings_are_refused_and_fresh_starts_again(tmp_path):
    assert run(tmp_path, "a")[0] == 0
    assert run(tmp_path, "a", "--seed", "12")[0] == 2
    assert run(tmp_path, "a", "--seed", "12", "--fresh")[0] == 0
    assert soak.load_state(tmp_path / "a" / "state.pkl")["settings"]["seed"] == 12


def test_a_changed_rig_is_simulated_told_and_kept_with_the_run(tmp_path):
    code, out = run(tmp_path, "rig", "--rig", "trace_adc_bits=12", "actuator_hysteresis=0")
    assert code == 0
    state = soak.load_state(out / "state.pkl")
    config = state["loop"].sim.config
    assert (config.trace_adc_bits, config.actuator_hysteresis) == (12, 0.0)
    assert config.dac_bits == 16  # the rest of the lab preset
    rig = {"actuator_hysteresis": 0, "trace_adc_bits": 12}
    assert state["settings"]["rig"] == rig
    assert json.loads((out / "summary.json").read_text())["rig"] == rig
    assert "`trace_adc_bits=12`" in (out / "page" / "index.md").read_text()
    assert run(tmp_path, "rig")[0] == 2  # resumed only with the same rig


@pytest.mark.parametrize(
    "rig, why",
    [
        ("latency_steps=2", "--latency-ms"),
        ("trace_adc_bits=99", "trace_adc_bits must be"),
        ("colour=3", "not a figure of the rig"),
    ],
)
def test_a_rig_figure_not_taken_exits_2_naming_it(tmp_path, capsys, rig, why):
    assert run(tmp_path, "bad", "--rig", rig)[0] == 2
    assert why in capsys.readouterr().err
    assert not (tmp_path / "bad" / "state.pkl").exists()


def test_a_run_stored_before_the_rig_settings_resumes(tmp_path):
    assert run(tmp_path, "old")[0] == 0
    path = tmp_path / "old" / "state.pkl"
    state = soak.load_state(path)
    for key in ("realism", "rig", "drift_turn_s"):
        del state["settings"][key]
    soak.save_state(state, path)
    assert run(tmp_path, "old")[0] == 0


def test_the_controllers_parameters_are_its_own_and_kept_with_the_run(tmp_path, capsys):
    code, out = run(tmp_path, "told", "--param", "hold_dither_cycles=0.02")
    assert code == 0
    state = soak.load_state(out / "state.pkl")
    assert state["loop"].ctl.params.hold_dither_cycles == 0.02
    assert state["settings"]["params"] == {"hold_dither_cycles": 0.02}
    assert "hold_dither_cycles=0.02" in (out / "page" / "index.md").read_text()
    assert run(tmp_path, "bad", "--param", "hold_dither_cycles=5")[0] == 2
    assert "hold_dither_cycles must be in" in capsys.readouterr().err


def test_the_drift_turn_is_simulated_and_kept_with_the_run(tmp_path, capsys):
    code, out = run(tmp_path, "turn", "--drift-turn-s", "90")
    assert code == 0
    state = soak.load_state(out / "state.pkl")
    assert state["loop"].sim.config.drift_turn_s == 90.0
    assert state["loop"].sim.noise.turn_steps == 900  # 90 s at 10 Hz
    assert state["settings"]["drift_turn_s"] == 90.0
    assert "the drift turning at its bound over 90 s" in (out / "page" / "index.md").read_text()
    assert run(tmp_path, "turn")[0] == 2  # resumed only with the same turn
    assert run(tmp_path, "bad", "--drift-turn-s", "-1")[0] == 2
    assert "--drift-turn-s must be from 0 to 3600 s" in capsys.readouterr().err
