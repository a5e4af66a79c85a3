"""Model-based phase retrieval with drift tracking: a stacking controller that needs no training.

The package: :mod:`.params` (the parameters, declared once), :mod:`.fit` (the fits as pure
functions), :mod:`.model` (the rig as the fits see it), and the state, each part with the module
that changes it: :mod:`.commands` (set-points, excursions, commands in flight), :mod:`.window` (the
readings), :mod:`.tracking` (the estimate, the priors of its fits, the false-lock rule),
:mod:`.drift_memory` (the drift remembered under a told vibration), :mod:`.noise` (the detector's
noise), :mod:`.vibration` (the delay lines' vibration as the fits see it), :mod:`.acquisition` (the
global search), :mod:`.knots` (the knot test), :mod:`.period` (whole-cycle moves, period correction)
and :mod:`.latency_check`; :mod:`.core` holds :class:`PhaseTracker`, the thin facade that runs a
reading through them.

The controller knows the stacker's physics (:class:`ops_sim_ros.physics.PulseStacker` built from
the *nominal* configuration: stage, wavelength, pulse width, detector) and estimates the hidden
delay errors x (one per stage, the part of each applied delay it did not command) from the stream
of (commanded set-points u_k, detected slot energies and power y_k) pairs:

    y_k ~ f(u_k + x_k),    x_k = x_t - (t - k) mu     (mu: each stage's drift per step)

One reading does not determine x (different delay vectors give the same slot energies, and x and
-x always do). The controller's own known moves are the phase diversity that makes the fit unique:
it fits x to the last ``window`` readings, taken at different set-points, by Levenberg-Marquardt
in units of optical cycles, and then commands u = -(x + mu) (the stacking point, with the drift
fed forward) plus a small known excursion.

* **Acquire** (no estimate): excursions of ``acquire_dither_cycles`` with random signs around the
  present set-points; once ``window`` readings are in, a global search scores ``candidates``
  random delay vectors over one period per stage against them and refines the ``refine`` best
  (with each stage's drift as well where a static fit does not explain the window). The estimate
  is accepted only when its residual is within ``residual_tolerance`` (plus the expected detector
  noise); otherwise the controller keeps its set-points, keeps dithering and searches again (it
  never moves on an estimate it does not trust). A search too large for one reading (N = 7,
  :mod:`.work`) runs ``spread_rows`` a reading and refines its estimate on the window as it is
  when it ends.
* **Track**: each reading re-fits the window as a path, a moving-horizon estimate: the errors at
  every reading of the window and one drift per stage, most probable given the readings, a random
  walk between readings (``walk_cycles`` per step; by default six times the model's jitter, so a
  rig noisier than nominal is still followed) and the drift's present estimate
  (``drift_prior_cycles``). The excursion is ``hold_dither_cycles`` on one stage at a time,
  alternating in sign, so the window stays diverse and the sign of a small error stays visible.
* **Recover**: ``misses`` fits in a row whose readings' residual exceeds ``lost_tolerance`` (a
  knot of the drift, a jump; a single one keeps the prediction) switch to acquisition-sized
  excursions around the prediction; after ``recover_readings`` readings the path is re-fitted to
  them from the present drift, no drift, and each stage's drift reversed; if that fails for a
  whole window, a global acquisition follows.
* **Knots** (a stage's drift changes slope): a tracking fit that does not explain its readings
  is tried again under one hypothesis per stage, knot position and side (``knot_*`` parameters).
  With ``defer_knot_test`` (the default, in the node and in process) that test waits until the
  command is out: :meth:`PhaseTracker.think` runs its ``knot_iterations`` (capped in real time by
  ``knot_budget_ms`` in the node) and tells the caller when the
  command it gave should be revised.
* **Answer first** (``answer_first``, off by default): a reading while tracking is answered by
  the drift's prediction from the last fit, and its tracking fit runs in
  :meth:`PhaseTracker.think` once the command is out, acting from the next command. A node's
  round trip then holds no fit: worth it where a step's drift is small (a fast loop in physical
  time), a cost where it is not (a 10 Hz loop).
* **One fit in so many** (``fit_every``, 1 by default): while tracking, the readings between
  two fits are answered by the drift's prediction and join the next fit's window (a reading
  with a whole-cycle move is always fitted): a node whose fit takes most of a fast loop's
  period spends a fraction of the CPU per reading.

Vibration (a model under ``time_base: seconds`` with a ``vibration`` preset, or the
``vibration`` parameter): each of the preset's components keeps cos(2 pi f step_s) of its value
from one reading to the next. Those that keep at least ``vibration_follow`` are followed as part
of the path (their move per step adds to the walk); the others are noise of each reading, not a
move of the path: a jitter about the path that shifts each entry's mean and adds to its variance
(both from the stacker, by draws at a tracking excursion), so the readings are weighed down by it
and every reading of the window speaks of the same slow path. Taken as a move of the path
instead, a 10 Hz loop's vibration (0.017 cycles over five lines, a correlation of 0.2 from one
reading to the next) let each reading's path point land on its mirror image wherever it exceeded
the excursion. Under a told vibration the fits also take the ``vibration_*`` settings: a walk of
``vibration_walk_factor`` times the model's jitter and a drift prior of
``vibration_drift_prior_cycles``, both per physical time (per step of ``step_s``), a window of
``vibration_window`` readings with a prior on its first errors from the last path taken
(``vibration_arrival_cycles``: the fit remembers more than its window), a smaller excursion on a
noisy detector (``vibration_dither_factor``), a knot test asked for only by a path step of
``vibration_knot_walk_sigmas`` (a stiff walk's few sigmas are the vibration's, not a knot) and a
drift remembered over ``vibration_memory_s``: each stage's slope of the estimates taken, the drift
prior's mean (std ``vibration_memory_prior_cycles``), a stage let go of alone where its estimates
leave its line by ``vibration_turn_cycles``, every stage where the whole drift reverses or a knot is
taken; then the fits' own drift under ``vibration_drift_prior_cycles``, no faster than twice the
slope let go of, until it fills again (:mod:`.drift_memory`).

Detector noise: the first two readings of an acquisition are taken at the same set-points; their
difference measures the noise variance, which widens the residual tolerance and the tracking
excursion (``detector_noise`` gives a floor when the noise is known); from a noise std of
``noisy_threshold`` on, fits take ``noisy_window`` readings instead of ``window``.

Assumptions, stated: the landscape is periodic in each delay with the optical period (the envelope
walk-off of a few cycles against a pulse of hundreds of fs is ignored), the random walk of the
delays over one window is small against the excursions, and detector noise is Gaussian with std
``detector_noise`` (0: noise-free readings; a residual floor is kept anyway). A model that does not
fit (a wrong wavelength or pulse width) raises the residual: the tolerance scales with the
readings' own spread, and the controller then falls back to acquiring rather than running away.
Set-points always move by the smallest step that reaches the target modulo one period and stay
within the actuator range.
"""

from .core import PhaseTracker
from .fit import PathFits
from .node_params import NODE_FIELDS, node_defaults, node_param_specs
from .noise import FIT_VAR_FITS, FIT_VAR_MIN
from .params import TrackerParams

__all__ = [
    "FIT_VAR_FITS",
    "FIT_VAR_MIN",
    "NODE_FIELDS",
    "PathFits",
    "PhaseTracker",
    "TrackerParams",
    "node_defaults",
    "node_param_specs",
]
