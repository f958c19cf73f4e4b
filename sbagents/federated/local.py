"""One home's learner: an SB3 model on the home's own env; its replay buffer and optimizers never leave it.

A round (:meth:`HomeLearner.train_round`): load the home's state from its own folder, take the global parameters,
train ``local_steps`` env steps on the home's experience (FedProx: with a proximal pull towards the global
parameters), save the state, and return the new parameters. Only the online networks are exchanged
(:func:`shared_state`); target networks stay local and keep tracking the online ones.
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.algos import ALGOS
from sbagents.atomic import save_model
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import Experiment, build_experiment
from sbagents.core.options import TrainSpec
from sbagents.env_factory import make_vec, normalize_for_training
from sbagents.federated.homes import Home
from sbagents.federated.settings import FederatedSettings
from sbagents.pipeline.models import make_model
from sbagents.safe_load import load_model
from sbagents.state_files import existing, load_replay_buffer, load_vecnormalize, save_replay_buffer

MODEL_FILE = "model.zip"
BUFFER_FILE = "replay_buffer.npz"


def home_experiment(settings: FederatedSettings, env_kwargs: dict[str, Any] | None = None,
                    n_timesteps: int | None = None) -> Experiment:
    """The zoo experiment every home trains (overrides applied); replay buffers sized to one home's whole run."""
    hyperparams = dict(settings.hyperparams)
    total = n_timesteps or settings.total_local_steps
    if ALGOS[settings.algo].off_policy:
        hyperparams.setdefault("buffer_size", total)
    spec = TrainSpec(settings.algo, settings.env, n_timesteps=total, hyperparams=hyperparams,
                     env_kwargs=env_kwargs or {})
    return build_experiment(spec, resolve_env(settings.env))


def make_env(exp: Experiment, seed: int, env_kwargs: list[dict[str, Any]] | None = None,
             stats_path: Path | None = None) -> VecEnv:
    """The training env of ``exp``. Observation normalization, if any, is fixed: the statistics of
    ``stats_path`` (a finished run's), else :func:`population_normalization` (the same for every home and the
    server, and read from no data).

    :param env_kwargs: one env per entry, each with its own kwargs (the centralized baseline: one per home).
    """
    from stable_baselines3.common.vec_env import DummyVecEnv

    from sbagents.private.training import freeze_normalization

    ref = resolve_env(exp.env_id)
    if env_kwargs is None:
        venv: VecEnv = make_vec(exp, ref, 1, seed, vec_env="dummy")
    else:
        parts = [make_vec(exp, ref, 1, seed + i, vec_env="dummy", env_kwargs=kw) for i, kw in enumerate(env_kwargs)]
        venv = DummyVecEnv([_first_env(p) for p in parts])
    found = existing(stats_path)
    if found is not None:
        loaded = load_vecnormalize(found, venv)
        loaded.training, loaded.norm_reward = False, False
        return loaded
    return population_normalization(freeze_normalization(normalize_for_training(venv, exp)))


def population_normalization(venv: VecEnv) -> VecEnv:
    """Fixed statistics of the user components from the population's ranges: an observation component named like
    one of the env's ``attribute_ranges`` (SmartHome: ``Preferred_Temp`` and ``preferred_temp``, 20-26 C) is scaled
    from that range to [-1, 1] instead of from its bounds (18-28 C).

    Public knowledge, not data. It matters for federated learning: within a home the user is a constant input,
    so only its variation *across* homes, centred, teaches the global policy to follow it (bounds-centred, the
    light preference of 50-80 lux is 0-0.6 for every home, and FedAvg learned a policy that ignores it).
    """
    if not isinstance(venv, VecNormalize) or not venv.norm_obs:
        return venv
    names = [str(n).lower() for n in venv.get_attr("obs_names", [0])[0]] if venv.has_attr("obs_names") else []
    ranges = venv.get_attr("attribute_ranges", [0])[0] if venv.has_attr("attribute_ranges") else {}
    rms: Any = venv.obs_rms
    for key, (low, high) in ranges.items():
        if key in names:
            i = names.index(key)
            rms.mean[i], rms.var[i] = (low + high) / 2, max((high - low) / 2, 1e-8) ** 2
    return venv


def _first_env(venv: VecEnv) -> Any:
    env = venv.envs[0]  # type: ignore[attr-defined]
    return lambda: env


def new_model(exp: Experiment, env: VecEnv, seed: int) -> BaseAlgorithm:
    """A fresh SB3 model of ``exp`` (1 torch thread is the caller's business)."""
    return make_model(exp, env, seed)


def shared_state(model: BaseAlgorithm) -> OrderedDict[str, torch.Tensor]:
    """The parameters a home exchanges: the policy's state without its target networks."""
    return OrderedDict((k, v.detach().cpu().clone()) for k, v in model.policy.state_dict().items()
                       if "_target." not in k)


def load_shared_state(model: BaseAlgorithm, state: dict[str, Any], sync_targets: bool = False) -> None:
    """Set the exchanged parameters of ``model`` (exactly the keys of :func:`shared_state`); with
    ``sync_targets`` the target networks are reset to the new online ones.

    :raises ValueError: names or shapes that are not this model's.
    """
    own = shared_state(model)
    if list(state) != list(own):
        raise ValueError(f"parameter names differ from the model's ({len(state)} given, {len(own)} expected)")
    tensors = {k: torch.as_tensor(np.asarray(v)) for k, v in state.items()}
    for key, value in tensors.items():
        if tuple(value.shape) != tuple(own[key].shape):
            raise ValueError(f"parameter {key}: shape {tuple(value.shape)}, expected {tuple(own[key].shape)}")
    model.policy.load_state_dict(tensors, strict=False)
    if sync_targets:
        full = model.policy.state_dict()
        targets = {k: full[k.replace("_target.", ".", 1)].clone() for k in full if "_target." in k}
        model.policy.load_state_dict(targets, strict=False)


def add_proximal_term(model: BaseAlgorithm, anchor: dict[str, torch.Tensor], mu: float) -> list[Any]:
    """FedProx: every optimizer step of ``model`` also descends ``mu/2 ||w - w_global||^2`` (adds
    ``mu (w - w_global)`` to each exchanged parameter's gradient). Returns the hook handles."""
    anchors = {p: anchor[name].to(p.device) for name, p in model.policy.named_parameters() if name in anchor}
    optimizers = {id(o): o for m in model.policy.modules() if isinstance(o := getattr(m, "optimizer", None),
                                                                          torch.optim.Optimizer)}

    def pull(optimizer: torch.optim.Optimizer, _args: Any, _kwargs: Any) -> None:
        with torch.no_grad():
            for group in optimizer.param_groups:
                for p in group["params"]:
                    if p.grad is not None and p in anchors:
                        p.grad.add_(p.detach() - anchors[p], alpha=mu)

    return [o.register_step_pre_hook(pull) for o in optimizers.values()]


class HomeLearner:
    """One home: its env (its user's preferences), its model, and its state folder.

    :param state_dir: the home's own storage (model, optimizers, replay buffer between rounds).
    """

    def __init__(self, settings: FederatedSettings, home: Home, state_dir: Path) -> None:
        self.settings, self.home, self.state_dir = settings, home, Path(state_dir)
        self.exp = home_experiment(settings, home.env_kwargs())
        self.seed = settings.seed * 1_000 + 101 * (home.index + 1)

    def train_round(self, global_state: dict[str, Any], server_round: int, proximal_mu: float = 0.0
                    ) -> OrderedDict[str, torch.Tensor]:
        """Train ``local_steps`` from ``global_state``; return the home's new exchanged parameters."""
        torch.set_num_threads(1)
        set_random_seed(self.seed + server_round)
        env = make_env(self.exp, self.seed + server_round)
        model_path = self.state_dir / MODEL_FILE
        first = not model_path.exists()
        if first:
            model = new_model(self.exp, env, self.seed)
        else:
            model = load_model(ALGOS[self.settings.algo].cls, model_path, env=env, device="cpu")
            if isinstance(model, OffPolicyAlgorithm) and (self.state_dir / BUFFER_FILE).exists():
                load_replay_buffer(model.replay_buffer, self.state_dir / BUFFER_FILE)
        load_shared_state(model, global_state, sync_targets=first)
        hooks = add_proximal_term(model, shared_state(model), proximal_mu) if proximal_mu > 0 else []
        model.learn(self.settings.local_steps, reset_num_timesteps=first)
        for hook in hooks:
            hook.remove()
        self.state_dir.mkdir(parents=True, exist_ok=True)
        save_model(model, model_path)
        if isinstance(model, OffPolicyAlgorithm) and model.replay_buffer is not None:
            save_replay_buffer(model.replay_buffer, self.state_dir / BUFFER_FILE)
        env.close()
        return shared_state(model)
