"""The paper's Table 1 (and Figures 7-11, 17): the benchmark and its report.

:mod:`.benchmark` (``ros2 run ops_gym_bridge benchmark``) plans runs from a profile
(``ops_experiments/ops_experiments/yaml/profiles.yaml``) and schedules them, locally or on Ray
(:mod:`.ray_pool`); :mod:`.bench_worker` executes one run (train through
:func:`ops_experiments.build.build_model`, evaluate through
:mod:`ops_experiments.subject`); :mod:`.report` (``ros2 run ops_gym_bridge report``)
writes the table, :mod:`.figures` the figures, from the stored runs alone.
"""
