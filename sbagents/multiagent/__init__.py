"""PettingZoo envs in SB3: :class:`~sbagents.multiagent.parameter_sharing.ParameterSharingVecEnv` (one policy for
every agent) and team evaluation (:mod:`~sbagents.multiagent.team_eval`)."""
