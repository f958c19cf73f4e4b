"""Private agents: DP-SGD training of SB3 actor-critics with Opacus (:func:`make_private`), Poisson-sampled replay
(:class:`PoissonReplayBuffer`) and rollouts (:class:`PoissonRolloutBuffer`, PPO and A2C), and the privacy ledger
(:mod:`sbagents.private.accounting`)."""
