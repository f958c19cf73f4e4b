"""The run pipeline: a validated experiment (:mod:`sbagents.core`) -> envs (:mod:`sbagents.env_factory`) -> model +
callbacks -> run dir.

- :mod:`~sbagents.pipeline.models`: the SB3 model of an experiment.
- :mod:`~sbagents.pipeline.training`, :mod:`~sbagents.pipeline.evaluation`, :mod:`~sbagents.pipeline.tuning`: SB3
  training, evaluation and Optuna search; :mod:`~sbagents.pipeline.backends` picks SB3 or RLlib.
- :mod:`~sbagents.pipeline.trust`, :mod:`~sbagents.pipeline.console`: trust callbacks wiring, console output.

The options, env refs, zoo configs, experiments and run dirs it works on are in :mod:`sbagents.core`, below every
feature package. This package imports nothing on its own; the public entry points are gathered in
:mod:`sbagents.api`.
"""
