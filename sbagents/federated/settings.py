"""The settings of a federated run, checked once, and their flat form for Flower's run config (deployment)."""

from __future__ import annotations

import math
import shlex
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from sbagents.capabilities import Capability
from sbagents.core.zoo_config import parse_overrides
from sbagents.errors import UsageError

#: The aggregation strategies (:mod:`sbagents.federated.strategies`).
STRATEGIES = ("fedavg", "fedprox", "dp-fedavg")
#: Envs with a population of homes (:mod:`sbagents.federated.homes`).
FEDERATED_ENVS = ("sbagents/SmartHome-v0",)
#: Algorithms a home can train (SB3 actor-critics for SmartHome's Box actions).
FEDERATED_ALGOS: tuple[str, ...] = ("a2c", "ppo", "ddpg", "td3", "sac")
#: Federated homes' column of the capability table (:data:`sbagents.registration.CAPABILITY_SOURCES` names
#: :func:`capabilities`).
FEDERATED_HOMES = Capability("federated", "federated homes (python -m sbagents.federated)", FEDERATED_ALGOS,
                             label="federated homes")


def capabilities() -> list[Capability]:
    """What federated homes declare for the capability table: :data:`FEDERATED_HOMES`."""
    return [FEDERATED_HOMES]


@dataclass
class FederatedSettings:
    """What a federated run trains and how (every field has the CLI's default).

    :param homes: number of client homes (>= 2); home ``i`` has taste ``i % 4`` (:func:`~.homes.client_homes`).
    :param rounds: federated rounds; each round every home trains ``local_steps`` env steps from the global model.
    :param strategy: ``fedavg``, ``fedprox`` (``proximal_mu``) or ``dp-fedavg`` (``dp_clip``, ``dp_noise``).
    :param dp_clip: DP-FedAvg: the L2 norm each home's update (its parameters minus the global ones) is clipped to.
    :param dp_noise: DP-FedAvg: the noise multiplier; the mean update gets N(0, (dp_noise dp_clip / homes)^2) noise.
    :param dp_delta: DP-FedAvg: the delta of the reported (user-level) epsilon.
    :param held_out: held-out homes the server evaluates the global model on after every round (0: none).
    :param eval_episodes: episodes per held-out home per evaluation.
    :param hyperparams: zoo config overrides (``-params``), the same for every home.
    """

    algo: str = "ddpg"
    env: str = "sbagents/SmartHome-v0"
    homes: int = 8
    rounds: int = 24
    local_steps: int = 250
    strategy: str = "fedavg"
    proximal_mu: float = 0.01
    dp_clip: float = 1.0
    dp_noise: float = 0.5
    dp_delta: float = 1e-3
    seed: int = 0
    held_out: int = 8
    eval_episodes: int = 2
    hyperparams: dict[str, Any] = field(default_factory=dict)

    def validate(self) -> None:
        """Raise :class:`UsageError` (one line naming the flag) for a value the run cannot use."""
        if self.algo not in FEDERATED_ALGOS:
            raise UsageError(f"--algo {self.algo}: federated homes train one of {', '.join(FEDERATED_ALGOS)}")
        if self.env not in FEDERATED_ENVS:
            raise UsageError(f"--env {self.env}: federated homes need an env with per-home users: "
                             f"{', '.join(FEDERATED_ENVS)}")
        if self.homes < 2:
            raise UsageError(f"--homes must be >= 2 (a federation), got {self.homes}")
        for flag, value in (("--rounds", self.rounds), ("--local-steps", self.local_steps)):
            if value < 1:
                raise UsageError(f"{flag} must be >= 1, got {value}")
        if self.strategy not in STRATEGIES:
            raise UsageError(f"--strategy {self.strategy!r} does not exist; use one of {', '.join(STRATEGIES)}")
        if not (math.isfinite(self.proximal_mu) and self.proximal_mu >= 0):
            raise UsageError(f"--proximal-mu must be >= 0, got {self.proximal_mu}")
        if not (math.isfinite(self.dp_clip) and self.dp_clip > 0):
            raise UsageError(f"--dp-clip must be > 0, got {self.dp_clip}")
        if not (math.isfinite(self.dp_noise) and self.dp_noise > 0):
            raise UsageError(f"--dp-noise must be > 0, got {self.dp_noise}")
        if not 0 < self.dp_delta < 1 / self.homes:
            raise UsageError(f"--dp-delta must be in (0, 1/{self.homes}) (one home is the unit), got {self.dp_delta}")
        if self.held_out < 0 or self.eval_episodes < 1:
            raise UsageError("--held-out must be >= 0 and --eval-episodes >= 1")

    @property
    def total_local_steps(self) -> int:
        """Env steps one home takes over the run."""
        return self.rounds * self.local_steps

    def to_run_config(self) -> dict[str, str | int | float | bool]:
        """The flat ``key=value`` form Flower's run config carries (``flwr run --run-config``)."""
        flat: dict[str, str | int | float | bool] = {}
        for key, value in asdict(self).items():
            flat[key.replace("_", "-")] = (shlex.join(f"{k}:{v}" for k, v in value.items())
                                           if key == "hyperparams" else value)
        return flat

    @classmethod
    def from_run_config(cls, config: dict[str, Any]) -> FederatedSettings:
        """The inverse of :meth:`to_run_config` (unknown keys are ignored; missing ones take the defaults)."""
        kwargs: dict[str, Any] = {}
        for f in fields(cls):
            key = f.name.replace("_", "-")
            if key in config:
                value = config[key]
                kwargs[f.name] = parse_overrides(shlex.split(str(value))) if f.name == "hyperparams" else value
        return cls(**kwargs)
