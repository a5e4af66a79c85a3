"""The experiment harness: train, evaluate, the rollouts and their one summary; the paper's Table 1.

* :mod:`.train` (``ros2 run ops_gym_bridge train``): the CLI; :mod:`.training_run` resolves a
  run's options (``--resume``, ``--init-from``), :mod:`.build` builds its env and model (the one
  path of ``train``, the benchmark and the training bench), :mod:`.learn` trains and saves.
* :mod:`.evaluate` (``ros2 run ops_gym_bridge evaluate``) on :mod:`.subject` (what is evaluated,
  on which environment) and :mod:`.rollouts` (the episode loops); :mod:`.summary` reduces
  episodes to the one schema of every ``evaluation.json``; :mod:`.continuous` (long runs),
  :mod:`.recording` (bags), :mod:`.realism_sweep`.
* :mod:`.hyperparams` (named sets, benchmark profiles and training-bench candidates: YAML files in
  ``yaml/``), :mod:`.envs`, :mod:`.rewards`, :mod:`.callbacks`.
* :mod:`.table1`: the paper's Table 1, ``benchmark`` and ``report``; :mod:`.cli_args`: what every
  command line shares.

The commands are installed under this package and under ``ops_gym_bridge`` (``ros2 run
ops_gym_bridge train``), whose bridge the harness trains over with ``--backend ros``.
"""
