"""The tracker's parameters, each declared once: default, meaning and allowed range.

:class:`TrackerParams` is the one default set: ``evaluate --controller tracker``, the benchmark
and the ``tracker`` node all start from it. A field declared with ``node=True`` is also a
parameter of the node (``ops_tracker``), whose :class:`~ops_contract.node_params.ParamSpec` is
generated from the same declaration (:mod:`.node_params`), so its name, description, range and
default cannot drift apart from the tracker's.

The one exception is a *real-time cap*, ``knot_budget_ms``: compute per reading in milliseconds
of the wall clock. A controller without a clock (in process) has no use for it and runs with
none (0); the node, which answers a free-running rig, caps its knot test at ``node_default``
(4 ms). The work itself is fixed by counts that hold on any machine (``knot_iterations``,
``search_units``), so the cap binds only where the machine is too slow for them
(docs/tracker.md, "One tracker for the node and evaluate"). ``step_budget_ms``, the same kind of
cap on the global search, is 0 in both: spread over readings the search failed in hard and
extreme mode.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

from ops_contract.config import VIBRATIONS


def _declare(
    default,
    doc: str,
    low=None,
    high=None,
    *,
    low_open: bool = False,
    choices: tuple = (),
    node: bool = False,
    node_default=None,
    optional: bool = False,
):
    """A field of :class:`TrackerParams` with its meaning and allowed values (``low`` / ``high``
    inclusive unless ``low_open``; ``choices`` for a string; ``optional``: None is allowed too;
    ``node``: also a parameter of the tracker node, there with ``node_default`` if given)."""
    meta = dict(
        doc=doc,
        low=low,
        high=high,
        low_open=low_open,
        choices=tuple(choices),
        node=node,
        node_default=node_default,
        optional=optional,
    )
    return field(default=default, metadata=meta)


def allowed_text(meta: dict) -> str:
    """The allowed values of a declared field, as an error message states them."""
    if meta["choices"]:
        return " or ".join(meta["choices"])
    low, high = meta["low"], meta["high"]
    if low is not None and high is not None:
        text = f"in {'(' if meta['low_open'] else '['}{low:g}, {high:g}]"
    elif low is not None:
        text = f"{'>' if meta['low_open'] else '>='} {low:g}"
    else:
        text = "any value"
    return text + (" or None" if meta["optional"] else "")


def _problem(name: str, meta: dict, value) -> str | None:
    """Why ``value`` is not allowed for the declared field ``name``, or None."""
    if value is None and meta["optional"]:
        return None
    if meta["choices"]:
        ok = value in meta["choices"]
    else:
        low, high = meta["low"], meta["high"]
        ok = not (low is not None and (value <= low if meta["low_open"] else value < low))
        ok = ok and not (high is not None and value > high)
    return None if ok else f"{name} must be {allowed_text(meta)} (got {value!r})"


@dataclass(frozen=True)
class TrackerParams:
    window: int = _declare(7, "readings per fit", 2, 64, node=True)
    # On a noisy detector (noise std, assumed or measured, >= noisy_threshold) a fit takes
    # max(window, noisy_window) readings: more readings average the noise, while a short window
    # follows the drift's knots sooner (docs/tracker.md weighs the two).
    noisy_window: int = _declare(
        10,
        "readings per fit once the detector is found noisy (the longer of the two is used)",
        2,
        64,
        node=True,
    )
    noisy_threshold: float = _declare(
        0.005,
        "measured noise std from which the detector counts as noisy",
        0.0,
        low_open=True,
    )
    # ... and the assumed or told noise (detector_noise, the rig's digitizer and source): lower,
    # for it is the detector's alone, while the repeated first reading also sees the delay lines
    # move between the two steps (a fast drift reads as a few 1e-3 there).
    told_noisy_threshold: float = _declare(
        0.0001,
        "assumed or told noise std from which the detector counts as noisy",
        0.0,
        low_open=True,
    )
    # ... and the noise the tracking fits find (the median over their last 25 of half the mean
    # squared change of the residuals from one reading to the next): the repeated first reading,
    # taken far from the optimum, also sees the lines' jitter, and the residuals' level also
    # holds the model's misfit, so neither tells a noise of a few 1e-4 from a clean detector.
    # Untold and taken as clean, such a noise is read as knots (docs/tracker.md).
    fit_noisy_threshold: float = _declare(
        0.0002,
        "noise std the tracking fits find, from which the detector counts as noisy (0: never)",
        0.0,
    )
    acquire_dither_cycles: float = _declare(
        0.02, "excursion per stage while acquiring, cycles", 0.0, 0.25, low_open=True
    )
    hold_dither_cycles: float = _declare(
        0.012, "excursion while tracking (its length over the stages)", 0.0, 0.25, node=True
    )
    # On a noisy detector the excursion is at least this many times the square root of the
    # noise std (cycles): a reading near the optimum is quadratic in the error, so the excursion
    # must lift its signal above the noise (docs/tracker.md).
    noisy_dither_factor: float = _declare(
        0.3, "tracking excursion on a noisy detector, times sqrt(noise std)", 0.0, 2.0
    )
    hold_pattern: str = _declare(
        "all",
        "tracking excursion: all stages at once (Hadamard signs) or one at a time",
        choices=("one", "all"),
        node=True,
    )
    # A fast drift needs a stronger probe (a knot must show in the next reading): the excursion
    # is at least this many times the fastest stage's estimated drift per step.
    drift_dither_gain: float = _declare(
        2.0, "the tracking excursion is at least this many times the fastest drift", 0.0, 10.0
    )
    candidates: int = _declare(512, "random delay vectors scored by the global search", 1)
    refine: int = _declare(8, "best candidates refined by Levenberg-Marquardt", 1)
    iterations: int = _declare(12, "LM iterations of a global refinement", 1)
    polish_iterations: int = _declare(
        4, "LM iterations that bring a search spread over readings up to the present window", 1
    )
    track_iterations: int = _declare(3, "LM iterations per reading while tracking", 1)
    walk_cycles: float | None = _declare(
        None,
        "random walk per step allowed, cycles (None: 6x the model's jitter)",
        0.0,
        low_open=True,
        optional=True,
    )
    # The delay lines' vibration (ops_sim_ros.vibration) at the loop's step: its components that
    # keep at least vibration_follow of their value from one reading to the next add to the
    # walk the path follows, the others are noise of each reading (.vibration). "model": the rig
    # model's vibration, read at its step_s (none under time_base step).
    # Not a node parameter: the tracker node's own vibration and step_s put its model in
    # physical time (tracker_node.physical_time), and this stays "model" there.
    vibration: str = _declare(
        "model",
        "the delay lines' vibration the fits allow for: a preset, none, or model (the rig model's)",
        choices=("model", *VIBRATIONS),
    )
    vibration_follow: float = _declare(
        0.9,
        "a vibration component that keeps this correlation over one step is followed as part "
        "of the path; the rest is noise of each reading",
        -1.0,
        1.0,
    )
    # Under a told vibration the readings are noisy whatever the detector, and a path fit that
    # follows them takes the vibration for the lines' walk: the fits take these settings instead
    # of the ones beside them (.vibration.under_vibration; docs/loop_rate.md, "The tracker").
    # A window's fit starts from what the fits before found: its first errors have a prior, the
    # last taken path's there with this std (a moving-horizon estimate's arrival cost), so a fit
    # remembers more readings than its window holds (0: none).
    vibration_arrival_cycles: float = _declare(
        0.003,
        "under a told vibration, std of the prior on a window's first errors from the fit "
        "before, cycles (0: none)",
        0.0,
    )
    vibration_walk_factor: float = _declare(
        1.0,
        "under a told vibration, the path fits' walk per step is this many times the model's "
        "jitter over that step (walk_cycles unset)",
        0.0,
        100.0,
        low_open=True,
    )
    vibration_drift_prior_cycles: float = _declare(
        0.0001,
        "under a told vibration, how far one window may move the drift estimate, cycles per "
        "0.1 s (std; also after a drift turn, knot or not)",
        0.0,
        low_open=True,
    )
    vibration_window: int = _declare(
        20, "under a told vibration, readings per fit (the longer of it and window)", 2, 64
    )
    vibration_dither_factor: float = _declare(
        0.2, "under a told vibration, noisy_dither_factor", 0.0, 2.0
    )
    # A digitized trace's rounding as the fits weigh it, in steps of its ADC (the rig's told
    # trace_adc_bits): alone it is 0.29 steps rms, but where the readings hold still near the
    # optimum it is a bias, and weighed as 0.6 steps the tracker held the paper's hard mode best
    # on an 8-bit trace (0.994, against 0.977 with 0.29 and 0.833 with none; docs/physics.md).
    # Under the lab vibration 0.3 (the rounding's own rms) raised the share of readings >= 0.95
    # and lost more locks at the drift's turns (docs/loop_rate.md, "The tracker under
    # vibration").
    quantization_noise_steps: float = _declare(
        0.6, "a digitized trace's rounding as the fits weigh it, ADC steps", 0.0, 10.0
    )
    vibration_knot_walk_sigmas: float = _declare(
        3.0,
        "under a told vibration, knot_walk_sigmas (clean or noisy detector)",
        0.0,
        low_open=True,
    )
    # A window's drift is mostly the walk and the vibration read as drift: under a told
    # vibration each stage's drift prior's mean is the slope of its estimates over the last
    # vibration_memory_s (std vibration_memory_prior_cycles), a stage let go of alone where its
    # window leaves that slope by vibration_turn_cycles, every stage where the whole drift
    # reverses (.drift_memory; docs/tracker.md).
    vibration_memory_s: float = _declare(
        120.0,
        "under a told vibration, seconds of estimates whose slope is the drift prior's mean "
        "(0: off)",
        0.0,
        3600.0,
    )
    # ... in a window this long or longer (shorter: its own drift follows the vibration)
    vibration_memory_min_window_s: float = _declare(
        0.1, "under a told vibration, the shortest window that takes the drift memory, s", 0.0
    )
    vibration_memory_prior_cycles: float = _declare(
        2e-5,
        "under a told vibration, the drift prior's std about the remembered slope, cycles per "
        "0.1 s",
        0.0,
        low_open=True,
    )
    vibration_turn_cycles: float = _declare(
        0.05,
        "under a told vibration, how far a window's estimates may leave the remembered slope "
        "(one stage's, or every stage's along the drift's reversal) before it is let go of, "
        "cycles",
        0.0,
        low_open=True,
    )
    drift_prior_cycles: float = _declare(
        0.004, "how far one window may move the drift estimate (std)", 0.0, low_open=True
    )
    noisy_drift_prior_cycles: float = _declare(
        0.001, "... on a noisy detector (docs/tracker.md)", 0.0, low_open=True
    )
    # ... and once no knot was taken for quiet_after readings: a drift that keeps its slope
    # (hard mode's, a slow thermal one) is followed best by a stiffer estimate, a drift whose
    # slope changes (extreme's knots, every 40-120 steps) by a looser one; the knots the
    # tracker takes tell the two apart on a rig whose mode nobody knows (0: off).
    quiet_drift_prior_cycles: float = _declare(
        0.0005,
        "... on a noisy detector with no knot taken for quiet_after readings (0: off)",
        0.0,
    )
    quiet_after: int = _declare(100, "readings without a knot taken that count as quiet", 1)
    # ... and the other way: within quiet_after readings of a knot taken, a drift whose slope
    # changes is followed by a looser estimate (docs/tracker.md). Never where no knot is
    # taken, as with the knot tests cut short (0: as noisy_drift_prior_cycles).
    knotted_drift_prior_cycles: float = _declare(
        0.002, "... on a noisy detector within quiet_after readings of a knot taken (0: off)", 0.0
    )
    # The fastest drift the tracker believes, cycles per step (a fit beyond is clipped): on a
    # periodic landscape a drift near a cycle per step reads like none, and knot hypotheses on
    # a model off in wavelength could run an estimate there; the modes' drifts stay far below.
    max_drift_cycles: float = _declare(
        0.1, "the fastest drift believed, cycles per step", 0.0, 0.5, low_open=True
    )
    residual_tolerance: float = _declare(
        1e-6, "mean squared residual that counts as a fit (to lock)", 0.0, low_open=True
    )
    # The least std of a reading about the model that the path fits assume (normalized
    # energies), added to what the fits' own residuals show (the model's accuracy on a clean
    # detector is ~1e-5): the readings' weight against the random walk and the drift prior.
    fit_noise_floor: float = _declare(
        3e-4, "least std of a reading about the model", 0.0, low_open=True
    )
    lost_tolerance: float = _declare(
        1e-5, "mean squared residual of a tracking fit that counts as lost"
    )
    detector_noise: float = _declare(
        0.0, "assumed detector noise std (normalized energies)", 0.0, 1.0, node=True
    )
    # A rig node computes ops/power from the trace it publishes (the sum of the squared slot
    # energies, clipped at 1; docs/rig.md): it adds nothing to the slot energies but their
    # full-scale error, squared, and a flat top. The fits then weigh it by this factor.
    power_weight: float = _declare(
        1.0,
        "weight of ops/power in the fits beside the slot energies (0: a power computed from "
        "the trace, as a rig node's)",
        0.0,
        1.0,
        node=True,
    )
    # ... and where it weighs nothing, nothing but the excursions pins the slot energies'
    # level: a detector gain a fraction of a percent off reads as delay errors of ~0.01 cycles,
    # which the excursions contradict (misfits, false knots, lost locks), and a rig's calibrated
    # full scale, or an acquisition's own fit of it, is off by that much. The tracking fits of
    # the first window after an acquisition's lock then fit the gain too, with this prior std
    # about the present one; later fits leave it to the detector's line (a gain free in every
    # fit would explain the level lost to a drift estimate run ahead, and take false knots).
    lock_gain_walk: float = _declare(
        0.005,
        "how far one tracking fit in the first window after a lock may move the detector's "
        "gain where power_weight is 0 (relative std; 0: never)",
        0.0,
        0.1,
    )
    # ... and the same for the offset: a detector's reading of no light a few 1e-4 of the full
    # scale off reads like light in every empty slot of the stack, which only delay errors make
    # (docs/rig.md, "The detector's offset, measured in every record").
    lock_offset_walk: float = _declare(
        0.0005,
        "how far one tracking fit in the first window after a lock may move the detector's "
        "offset where power_weight is 0 (normalized energies, std; 0: never)",
        0.0,
        0.1,
    )
    # The detector's line fitted again at a lock takes only the readings since the lock that
    # read this much power or more where power_weight is 0: away from the stack a delay error
    # moves the slot energies as much as the gain does, and a refit on such readings puts the
    # gain percents off; near the stack they measure it.
    lock_refit_power: float = _declare(
        0.95,
        "the least P_N/P_max of a reading the detector's line is fitted again on at a lock, "
        "where power_weight is 0",
        0.0,
        1.0,
    )
    misses: int = _declare(3, "bad fits in a row before recovering", 1)
    # Knots of the drift (a stage's slope changes): a tracking fit whose residual exceeds
    # knot_tolerance (or whose path jumps, knot_walk_sigmas) is tried again under one hypothesis
    # per stage, knot position (the window's last knot_readings steps) and side: from the knot
    # on, that stage's drift changes by a variable with prior std knot_prior_cycles (0: never
    # try); a hypothesis is taken if its whole cost plus knot_penalty is the lowest. The prior
    # keeps the hypotheses off the mirror images of a change (a path that reads the same with
    # the change's sign turned, at twice its size); `ops-bench tracker-knots` measures it.
    knot_tolerance: float = _declare(
        1e-6, "residual of a tracking fit that asks for the knot test", 0.0, low_open=True
    )
    knot_prior_cycles: float = _declare(
        0.015, "prior std of a knot's change of drift (0: no knot test)", 0.0
    )
    knot_start_cycles: float = _declare(0.02, "the knot fits start this far off the prediction")
    knot_readings: int = _declare(3, "a knot is looked for in the window's last readings", 1)
    # ... on a noisy detector: a knot shows through the noise readings later, often after the
    # last three, and a test that cannot place it there takes a wrong stage or side
    # (docs/tracker.md). A clean detector keeps 3: 5 is 60 % more hypotheses, which a real-time
    # budget would cut short.
    noisy_knot_readings: int = _declare(5, "... on a noisy detector", 1)
    knot_iterations: int = _declare(
        6, "LM iterations of the knot hypotheses per knot test", 1, 100, node=True
    )
    noisy_knot_iterations: int = _declare(12, "... on a noisy detector", 1)
    # After knot_prune_after iterations only the knot_keep best hypotheses iterate on (0: all):
    # the Jacobians of the losing hypotheses are most of the knot test's compute.
    knot_prune_after: int = _declare(2, "iterations before the knot hypotheses are pruned", 0)
    knot_keep: int = _declare(0, "knot hypotheses kept after pruning (0: all)", 0)
    # A real-time cap on the knot test, ms (0: none): a rig steps on its own clock, and a knot
    # test's outcome is worth most before the next step (the node: 4 ms; in process: none).
    knot_budget_ms: float = _declare(
        0.0,
        "real-time cap on the knot test and the fits after it per reading, ms (0: none)",
        0.0,
        1000.0,
        node=True,
        node_default=4.0,
    )
    # On a noisy detector a knot test (51 hypotheses x 12 iterations at N = 5) can need more
    # than one reading's budget, and a test cut short is left inconclusive. Spread, the test
    # runs on over the next readings within each one's budget (its window and hypotheses kept),
    # and a winner is tried again on the window of the reading it ends at, against no knot,
    # before it is taken (docs/tracker.md, "A knot test spread over readings").
    slice_knot_test: bool = _declare(
        True,
        "true: on a noisy detector, a knot test its budget would cut short runs on over the "
        "next readings",
        node=True,
    )
    # A budget of work per reading for the knot test, counted in rows the physics evaluates
    # (delay vectors, each weighed as (2^N / 32)^2 rows at N = 5: its matrix product's share), so
    # that it holds on any machine: a test whose work (knots.test_rows) would exceed it is spread
    # over the next readings, each running as much of it as fits (at least one unit). The default
    # holds whole every test at N <= 5 (the largest, a noisy detector's: 46,410 rows) and spreads
    # those at N = 7 (a clean detector's: 303,408), each of which takes many 100 Hz steps.
    work_budget: float = _declare(
        50000.0,
        "most work per reading on a knot test, in rows evaluated at N = 5 (0: none)",
        0.0,
    )
    knot_walk_sigmas: float = _declare(
        2.0, "a path step this far off the drift (walk stds) asks for the knot test"
    )
    # ... on a noisy detector, where a knot shows late through the noise (kept at 2.0 on a
    # clean one: each test is compute a real-time budget may cut short)
    noisy_knot_walk_sigmas: float = _declare(1.5, "... on a noisy detector")
    knot_penalty: float = _declare(4.0, "a knot hypothesis wins if its cost + this is lowest")
    # ... on a noisy detector (noise std >= noisy_threshold) the knot test fires on the noise
    # far more often, and a hypothesis must win by this much (docs/tracker.md)
    noisy_knot_penalty: float = _declare(8.0, "... on a noisy detector", 0.0)
    # Answer first, test for knots after: the command after a suspicious reading aims by the
    # plain fit and the knot test runs once it is out (think()), its outcome acting from the
    # next command. In real time a knot test may not fit before a 100 Hz rig's next step: done
    # first, the command would come a step late, exactly after the knots (docs/tracker.md).
    defer_knot_test: bool = _declare(
        True,
        "true: answer a reading first and test it for a knot of the drift after",
        node=True,
    )
    # Answer every reading first, fit after: the command aims by the drift's prediction from
    # the last fit and the reading's tracking fit runs once it is out (think()), acting from the
    # next command. Over DDS the round trip then holds no fit: a loop fast enough that a step's
    # drift and walk are small (time_base seconds) keeps its rate where the fit would make it
    # miss steps (docs/loop_rate.md); at the paper's 0.1 s a step the lag costs more.
    answer_first: bool = _declare(
        False,
        "true: answer each reading by the prediction and fit it after the command is out",
        node=True,
    )
    # Fit one reading in fit_every while tracking: the others are answered by the drift's
    # prediction and join the next fit's window (a whole-cycle move's reading is always fitted).
    # A node whose fit takes most of a fast loop's period (500 Hz over DDS on two cores) thus
    # keeps its rate; the window still holds every reading (docs/loop_rate.md).
    fit_every: int = _declare(
        1,
        "while tracking, fit one reading in this many; the others are answered by the "
        "prediction and join the next fit's window",
        1,
        100,
        node=True,
    )
    recover_readings: int = _declare(4, "readings after a failed fit before a local re-fit", 2)
    acquire_drift: bool = _declare(True, "fit each stage's drift too when a static fit fails")
    # The global search and each candidate of the latency check run whole in the reading that
    # starts them while their work (tracker.work: rows evaluated, weighed to N = 5) is within
    # search_work_budget: at N <= 5 (a search is about 30,000 rows, some 24 ms). Beyond it (N = 7:
    # about 570,000, a latency candidate 350,000) they run spread_rows a reading (about 8 ms),
    # the commands keeping their known excursions meanwhile, and a spread search refines what it
    # found on the window as it is when it ends (polish_iterations).
    search_work_budget: float = _declare(
        100000.0,
        "most work of a global search or latency-check candidate run in one reading, rows "
        "evaluated at N = 5 (0: no limit)",
        0.0,
    )
    spread_rows: float = _declare(
        8000.0,
        "work per reading of a search spread over readings, rows at N = 5",
        1.0,
        node=True,
    )
    # search_units and step_budget_ms spread any search by a count or a time: a search spread
    # so, at N = 5, lost episodes in hard mode before it refined its estimate on the present
    # window (docs/tracker.md, "One tracker for the node and evaluate").
    search_units: int = _declare(
        0, "units of the global search per reading (0: all in one reading)", 0, 10000, node=True
    )
    step_budget_ms: float = _declare(
        0.0,
        "real-time cap on the global search per reading, ms (0: none)",
        0.0,
        1000.0,
        node=True,
    )
    # Told of an open-loop piezo's hysteresis (actuator_hysteresis), drive the lines through
    # its inverse so that they go where the tracker means them to (tracker.hysteresis).
    compensate_hysteresis: bool = _declare(
        True,
        "true: drive the lines through the inverse of the told actuator hysteresis",
        node=True,
    )
    calibrate: bool = _declare(True, "estimate the detector's gain and offset online")
    calibrate_optics: bool = _declare(
        False, "estimate wavelength and pulse width too (experimental)"
    )
    calibration_every: int = _declare(
        25, "tracking readings between updates of wavelength and pulse width", 1
    )
    calibration_memory: float = _declare(
        500.0, "readings over which the calibration statistics are kept", 1.0
    )
    # Readings without lock after which the detector's gain and offset go back to nominal: a fit
    # to a wrong estimate, or to readings that did not belong together (a starved machine), must
    # not keep the tracker from ever locking again.
    calibration_reset_after: int = _declare(
        500, "readings without lock before the detector calibration goes back to nominal", 1
    )
    # A "lock" with more than half of its last false_lock_readings readings below
    # false_lock_power is no lock: the estimate is dropped, the detector calibration goes back to
    # nominal and the tracker acquires again (0: never): a wrong estimate that the detector
    # gain's fit follows can otherwise stay "locked" at a low power for good. More than half,
    # not all in a row: a wrong lock whose knots jump it about reads high now and then.
    false_lock_power: float = _declare(
        0.5, "a lock whose readings are mostly below this is dropped", 0.0, 1.0
    )
    false_lock_readings: int = _declare(
        50, "... more than half of its last this many readings (0: never)", 0
    )
    # Wavelength from known whole-cycle moves: every hop_every tracking readings one stage's
    # set-point moves by hop_cycles periods of the model (the landscape repeats, so the lock
    # stays where the model is right); a model period off by a fraction r moves that stage's
    # phase by hop_cycles * r, which the path fits of the next readings measure (r is fitted
    # with the path), and the wavelength is corrected by hop_gain of it per fit (0: no moves).
    # A move waits for a clean lock (no knot in the window, a reading >= 0.98, the stage's drift
    # < 0.005 cycles per step).
    hop_every: int = _declare(
        10,
        "readings between whole-cycle moves that measure the wavelength (0: none)",
        0,
        100000,
        node=True,
    )
    # ... on a detector told noisy (told_noisy_threshold: the rig's digitizer, source and
    # detector): its period fits wander, and the wavelength with them (docs/tracker.md, "Noisy
    # from 0.0015")
    noisy_hop_every: int = _declare(
        0,
        "readings between whole-cycle moves on a detector told noisy (0: none)",
        0,
        100000,
        node=True,
    )
    hop_cycles: int = _declare(2, "periods of a whole-cycle move", 1, 10)
    # A latency the tracker was not told, or a wrong one: once three quarters of the
    # last latency_check_after readings are below latency_check_below, the last readings are
    # re-paired with the commands under each latency up to latency_check_longest and the one
    # they fit is taken (.latency_check).
    latency_check_after: int = _declare(
        20,
        "readings of which 3/4 below latency_check_below start a latency check (0: never)",
        0,
        100000,
        node=True,
    )
    latency_check_below: float = _declare(
        0.5, "reading below which the latency check counts", 0.0, 1.0, low_open=True
    )
    latency_check_longest: int = _declare(
        4, "longest latency the check tries, steps", 1, 100, node=True
    )
    hop_gain: float = _declare(
        0.05, "share of a measured period error corrected per fit", 0.0, 1.0, low_open=True
    )

    def __post_init__(self):
        for f in fields(self):
            problem = _problem(f.name, f.metadata, getattr(self, f.name))
            if problem:
                raise ValueError(problem)
        if self.false_lock_power >= 1.0:
            raise ValueError(f"false_lock_power must be in [0, 1) (got {self.false_lock_power!r})")
        if self.refine > self.candidates:
            raise ValueError(f"refine must be in [1, candidates] (got {self.refine!r})")
        if self.recover_readings > self.window:
            raise ValueError(
                f"recover_readings must be in [2, window] (got {self.recover_readings!r})"
            )

    def to_dict(self) -> dict:
        return asdict(self)
