"""The run pipeline: CLI options -> zoo config -> experiment -> env factory -> model + callbacks -> run dir.

- :mod:`~sbagents.pipeline.options`: the option groups (what to train, where to write, evaluation, execution).
- :mod:`~sbagents.pipeline.zoo_config`, :mod:`~sbagents.pipeline.experiment`: RL Zoo config files -> a validated
  :class:`~sbagents.pipeline.experiment.Experiment`.
- :mod:`~sbagents.pipeline.env_names`, :mod:`~sbagents.pipeline.env_factory`: ``--env`` names -> vectorised envs.
- :mod:`~sbagents.pipeline.models`: the SB3 model of an experiment.
- :mod:`~sbagents.pipeline.run_dir`, :mod:`~sbagents.pipeline.lifecycle`: run dirs (:class:`RunRef` finds one) and
  the life of a run shared by both backends.
- :mod:`~sbagents.pipeline.training`, :mod:`~sbagents.pipeline.evaluation`, :mod:`~sbagents.pipeline.tuning`: SB3
  training, evaluation and Optuna search; :mod:`~sbagents.pipeline.backends` picks SB3 or RLlib.
- :mod:`~sbagents.pipeline.trust`, :mod:`~sbagents.pipeline.console`: trust callbacks wiring, console output.

This package imports nothing on its own, so that light modules (``run_dir`` for ``serve``) stay light; the public
entry points are gathered in :mod:`sbagents.api`.
"""
