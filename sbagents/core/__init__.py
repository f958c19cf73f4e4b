"""The lowest layer of the run pipeline: what every other part of sbagents may use. Of the rest of sbagents it uses
only :mod:`sbagents.algos` (the algorithm table), :mod:`sbagents.capabilities` (what a feature declares it supports)
and :mod:`sbagents.registration` (env ids and module paths), never a feature package (checked by import-linter).

- :mod:`~sbagents.core.options`, :mod:`~sbagents.core.team_options`, :mod:`~sbagents.core.selfplay_options`: the
  option types of a run.
- :mod:`~sbagents.core.env_names`: ``--env`` names -> :class:`~sbagents.core.env_names.EnvRef`.
- :mod:`~sbagents.core.zoo_config`, :mod:`~sbagents.core.experiment`, :mod:`~sbagents.core.image_obs`: RL Zoo
  config files -> a validated :class:`~sbagents.core.experiment.Experiment`.
- :mod:`~sbagents.core.run_dir`, :mod:`~sbagents.core.lifecycle`, :mod:`~sbagents.core.monitor_files`: run dirs
  (:class:`~sbagents.core.run_dir.RunRef` finds one), the life of a run shared by every backend, monitor files.
- :mod:`~sbagents.core.extensions`: the training-extension API (declarations, phase hooks, registry), public as
  :mod:`sbagents.extensions`.
- :mod:`~sbagents.core.info_keys`: the ``info`` keys envs, wrappers and callbacks agree on (``ACTED``, ...).

The layers above, lowest first: ``sbagents.envs`` and ``sbagents.callbacks``; the feature packages
(``multiagent``, ``games``, ``private``, ...); ``sbagents.pipeline``; the CLIs and ``sbagents.api``. A module never
imports one of a higher layer, not even inside a function (``lint-imports``, configured in pyproject.toml). Like
:mod:`sbagents.pipeline`, this package imports nothing on its own.
"""
