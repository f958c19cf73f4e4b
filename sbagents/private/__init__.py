"""Private agents: DP-SGD training of SB3 actor-critics with Opacus (:func:`make_private`), Poisson-sampled replay
(:class:`PoissonReplayBuffer`) and rollouts (:class:`PoissonRolloutBuffer`, PPO and A2C), and the privacy ledger
(:mod:`sbagents.private.accounting`)."""


def require_opacus() -> None:
    """Import Opacus, the library this package trains with (``ImportError`` when it is missing): callers outside
    the package check for it here rather than importing it themselves."""
    import opacus  # noqa: F401
