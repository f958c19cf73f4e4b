"""Export a trained SB3 policy to ONNX (optionally int8) for torch-free inference (``sbagents.serve``).

The exported graph maps a raw observation batch to the action ``model.predict(deterministic=True)``
returns: VecNormalize observation normalization (``clip((obs - mean) / sqrt(var + eps), -clip, clip)``),
the deterministic policy, tanh squashing and rescaling to the Box bounds (or clipping, for unsquashed
Gaussian policies) are all inside the graph. Discrete actions come out as the int64 argmax index;
Discrete observations go in as an int64 index (one-hot inside the graph).

A recurrent policy (sb3-contrib's ``RecurrentPPO``, ``ppo_lstm``) is exported with its memory as inputs and
outputs: ``obs``, ``state_h``, ``state_c`` (each ``(n_layers, batch, hidden)``, zeros at the first step) and
``episode_start`` ``(batch,)`` float32 (1.0 where an episode starts: the state is reset there, as
``RecurrentPPO.predict`` does) -> ``action``, ``state_h_out``, ``state_c_out``; a caller feeds the outputs back as
the next step's state.

We use the legacy TorchScript exporter (``dynamo=False``): it needs no ``onnxscript`` and traces SB3's
distributions as they are; its deprecation warning is silenced locally. Argument validation of
``torch.distributions`` is switched off while tracing (it would add data-dependent checks) and restored.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.running_mean_std import RunningMeanStd

OBS_INPUT = "obs"
ACTION_OUTPUT = "action"
#: A recurrent graph's extra inputs (hidden and cell state, episode starts) and outputs (the next state).
STATE_INPUTS: tuple[str, str] = ("state_h", "state_c")
START_INPUT = "episode_start"
STATE_OUTPUTS: tuple[str, str] = ("state_h_out", "state_c_out")
ONNX_OPSET = 17


class OnnxPolicy(torch.nn.Module):
    """Raw observation ``(batch, obs_dim)`` (or ``(batch,)`` int64 for Discrete) -> action
    ``(batch, act_dim)`` float32 for Box, ``(batch,)`` int64 for Discrete.

    :param model: the trained SB3 algorithm.
    :param obs_rms: VecNormalize observation statistics to bake in (None: no normalization).
    :param clip_obs: VecNormalize ``clip_obs``.
    :param epsilon: VecNormalize ``epsilon``.
    :param channels_last: the graph takes images ``(batch, H, W, C)`` as the env gives them and transposes them to
        the ``(batch, C, H, W)`` SB3's CNN policies see (SB3's ``VecTransposeImage``); the policy scales them by
        1/255 itself.
    """

    obs_mean: torch.Tensor
    obs_scale: torch.Tensor
    act_low: torch.Tensor
    act_high: torch.Tensor

    def __init__(
        self,
        model: BaseAlgorithm,
        obs_rms: RunningMeanStd | None = None,
        clip_obs: float = 10.0,
        epsilon: float = 1e-8,
        channels_last: bool = False,
    ) -> None:
        super().__init__()
        self.policy = model.policy
        self.channels_last = channels_last
        self.action_space = model.action_space
        self.clip_obs = float(clip_obs)
        self.normalize = obs_rms is not None
        if obs_rms is not None:
            self.register_buffer("obs_mean", torch.as_tensor(obs_rms.mean, dtype=torch.float32))
            scale = np.sqrt(obs_rms.var + epsilon)
            self.register_buffer("obs_scale", torch.as_tensor(scale, dtype=torch.float32))
        self.box = isinstance(self.action_space, spaces.Box)
        if self.box:
            assert isinstance(self.action_space, spaces.Box)
            self.register_buffer("act_low", torch.as_tensor(self.action_space.low, dtype=torch.float32))
            self.register_buffer("act_high", torch.as_tensor(self.action_space.high, dtype=torch.float32))
        self.squash = bool(getattr(self.policy, "squash_output", False))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        obs = self._prepare(obs)
        actor_actions = getattr(self.policy, "actor_actions", None)  # a centralized critic: the actor alone
        action = actor_actions(obs) if actor_actions is not None else self.policy._predict(obs, deterministic=True)
        return self._finish(action)

    def _prepare(self, obs: torch.Tensor) -> torch.Tensor:
        """Raw observations -> what the SB3 policy takes (normalized, channels first)."""
        if self.normalize:  # VecNormalize's statistics are in the env's layout, before SB3's transposition
            obs = torch.clamp((obs - self.obs_mean) / self.obs_scale, -self.clip_obs, self.clip_obs)
        if self.channels_last:
            obs = obs.permute(0, 3, 1, 2)
        return obs

    def _finish(self, action: torch.Tensor) -> torch.Tensor:
        """The policy's actions -> the env's (int64 index, or rescaled / clipped to the Box bounds)."""
        if not self.box:
            return action.long()
        action = action.float().reshape((-1, *self.act_low.shape))
        if self.squash:
            return self.act_low + 0.5 * (action + 1.0) * (self.act_high - self.act_low)
        return torch.max(torch.min(action, self.act_high), self.act_low)


class OnnxRecurrentPolicy(OnnxPolicy):
    """A recurrent (LSTM) actor: ``(obs, state_h, state_c, episode_start) -> (action, state_h_out, state_c_out)``.

    The actor's LSTM step is written out (features, state reset where ``episode_start`` is 1, one LSTM step, the
    actor MLP, the deterministic action) rather than traced through sb3-contrib's ``_process_sequence``, whose
    "no episode starts" shortcut is a data-dependent branch a trace would freeze; both compute the same step.
    States are ``(n_layers, batch, hidden)`` float32, ``episode_start`` ``(batch,)`` float32.
    """

    def forward(  # type: ignore[override]
        self, obs: torch.Tensor, state_h: torch.Tensor, state_c: torch.Tensor, episode_start: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        from stable_baselines3.common.policies import BaseModel

        policy: Any = self.policy
        features = BaseModel.extract_features(policy, self._prepare(obs), policy.pi_features_extractor)
        keep = (1.0 - episode_start).view(1, -1, 1)
        out, (h, c) = policy.lstm_actor(features.unsqueeze(0), (keep * state_h, keep * state_c))
        latent = policy.mlp_extractor.forward_actor(out.squeeze(0))
        action = policy._get_action_dist_from_latent(latent).get_actions(deterministic=True)
        return self._finish(action), h, c


def is_recurrent_policy(model: BaseAlgorithm) -> bool:
    """Whether ``model``'s policy keeps an LSTM state (sb3-contrib's recurrent policies)."""
    return hasattr(model.policy, "lstm_hidden_state_shape")


def state_shape(model: BaseAlgorithm) -> tuple[int, int] | None:
    """``(n_layers, hidden)`` of a recurrent policy's actor state (each of ``h`` and ``c``), else None."""
    shape = getattr(model.policy, "lstm_hidden_state_shape", None)
    return (int(shape[0]), int(shape[2])) if shape is not None else None


def actor_observation_space(model: BaseAlgorithm) -> spaces.Space[Any]:
    """What the exported policy takes: the model's observation space, or the actor's own part of it (a centralized
    critic's policy acts on the agent's observation alone)."""
    return getattr(model.policy, "actor_observation_space", model.observation_space)  # type: ignore[no-any-return]


def taken_observation_space(model: BaseAlgorithm, env_space: spaces.Space[Any] | None = None) -> spaces.Space[Any]:
    """The observations an exported policy takes: ``env_space`` (what the env, wrappers included, gives) when it is
    the channels-last ``(H, W, C)`` form of the model's channels-first image space (SB3 transposed the env's images
    for its CNN), else :func:`actor_observation_space`."""
    own = actor_observation_space(model)
    if (isinstance(env_space, spaces.Box) and isinstance(own, spaces.Box) and len(own.shape) == 3
            and env_space.shape == (*own.shape[1:], own.shape[0]) and env_space.shape != own.shape):
        return env_space
    return own


def predict_actions(model: BaseAlgorithm, observations: np.ndarray) -> np.ndarray:
    """Greedy SB3 actions for a batch of (already normalized) actor observations ``(N, *obs_shape)`` (a recurrent
    policy: each as the first step of an episode, from a zero state)."""
    predict_actor = getattr(model.policy, "predict_actor", None)
    if predict_actor is not None:
        return np.asarray(predict_actor(observations))
    return np.asarray(model.predict(observations, deterministic=True)[0])  # type: ignore[arg-type]


def _dummy_obs(space: spaces.Space[Any]) -> torch.Tensor:
    if isinstance(space, spaces.Discrete):
        return torch.zeros((1,), dtype=torch.int64)
    if isinstance(space, spaces.Box):
        return torch.as_tensor(space.sample()[None], dtype=torch.float32)
    raise TypeError(f"only Box and Discrete observation spaces can be exported, got {space}")


def export_onnx(
    model: BaseAlgorithm,
    out_path: str | Path,
    obs_rms: RunningMeanStd | None = None,
    clip_obs: float = 10.0,
    epsilon: float = 1e-8,
    obs_space: spaces.Space[Any] | None = None,
) -> Path:
    """Write ``model``'s deterministic policy (with normalization and action rescaling baked in) as ONNX.

    :param model: a DQN, PPO, RecurrentPPO, A2C, SAC, TD3 or DDPG model (Box or Discrete actions).
    :param out_path: destination ``.onnx`` file (parents are created).
    :param obs_rms: ``VecNormalize.obs_rms`` when the model was trained on normalized observations.
    :param clip_obs: ``VecNormalize.clip_obs``.
    :param epsilon: ``VecNormalize.epsilon``.
    :param obs_space: the observations the graph takes (default: the model's): a channels-last image space
        (:func:`taken_observation_space`) puts the transposition SB3 does for CNNs inside the graph.
    :return: the written path. Input ``obs`` ``(batch, *obs_shape)`` float32 (int64 ``(batch,)`` for
        Discrete observations), output ``action`` ``(batch, *act_shape)`` float32 or ``(batch,)`` int64; a recurrent
        policy's graph also has the state inputs and outputs of :class:`OnnxRecurrentPolicy`.
    """
    if not isinstance(model.action_space, spaces.Box | spaces.Discrete):
        raise TypeError(f"only Box and Discrete action spaces can be exported, got {model.action_space}")
    if obs_rms is not None and not isinstance(obs_rms, RunningMeanStd):
        raise TypeError("obs_rms must be a RunningMeanStd (dict observations are not supported)")
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    device = model.policy.device
    own = actor_observation_space(model)
    taken = obs_space if obs_space is not None else own
    if taken.shape != own.shape and taken_observation_space(model, taken) is not taken:
        raise TypeError(f"the policy takes observations of shape {own.shape}, not {taken.shape}")
    channels_last = taken.shape != own.shape
    recurrent = state_shape(model)
    cls = OnnxRecurrentPolicy if recurrent is not None else OnnxPolicy
    wrapper = cls(model, obs_rms, clip_obs, epsilon, channels_last).cpu().eval()  # moves model.policy to CPU
    model.policy.set_training_mode(False)
    dummy: tuple[torch.Tensor, ...] = (_dummy_obs(taken),)
    inputs, outputs = [OBS_INPUT], [ACTION_OUTPUT]
    axes: dict[str, dict[int, str]] = {OBS_INPUT: {0: "batch"}, ACTION_OUTPUT: {0: "batch"}}
    if recurrent is not None:
        layers, hidden = recurrent
        zeros = torch.zeros((layers, 1, hidden), dtype=torch.float32)
        dummy = (*dummy, zeros, zeros.clone(), torch.ones((1,), dtype=torch.float32))
        inputs += [*STATE_INPUTS, START_INPUT]
        outputs += list(STATE_OUTPUTS)
        axes.update({name: {1: "batch"} for name in (*STATE_INPUTS, *STATE_OUTPUTS)})
        axes[START_INPUT] = {0: "batch"}
    validate = torch.distributions.Distribution._validate_args
    torch.distributions.Distribution.set_default_validate_args(False)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", FutureWarning)
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            # the LSTM's initial state is a graph input here, which is what this warning asks for
            warnings.filterwarnings("ignore", message="Exporting a model to ONNX with a batch_size other than 1")
            torch.onnx.export(
                wrapper,
                dummy,
                str(out),
                dynamo=False,
                input_names=inputs,
                output_names=outputs,
                dynamic_axes=axes,  # type: ignore[arg-type]
                opset_version=ONNX_OPSET,
            )
    finally:
        torch.distributions.Distribution.set_default_validate_args(validate)
        model.policy.to(device)  # back where the caller had it
    return out


def quantize_int8(src: str | Path, dst: str | Path) -> Path:
    """Dynamic int8 weight quantization of an ONNX file (``onnxruntime.quantization``, QInt8 weights)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    # onnxruntime logs a root-logger hint about shape pre-processing; it changes nothing for these MLPs
    # (measured: identical int8 weights), so drop that one message while quantizing.
    hint = _DropMessage("Please consider to run pre-processing")
    logging.getLogger().addFilter(hint)
    try:
        quantize_dynamic(str(src), str(dst), weight_type=QuantType.QInt8)
    finally:
        logging.getLogger().removeFilter(hint)
    return dst


class _DropMessage(logging.Filter):
    def __init__(self, prefix: str) -> None:
        super().__init__()
        self.prefix = prefix

    def filter(self, record: logging.LogRecord) -> bool:  # noqa: D102
        return not str(record.msg).startswith(self.prefix)


def check_exportable(model: BaseAlgorithm) -> None:
    """Raise ``TypeError`` (one line: what is wrong, what works) unless ``model`` can be exported to ONNX."""
    if not any(p.requires_grad for p in model.policy.parameters()):
        raise TypeError(
            f"export writes neural-network policies to ONNX; {type(model).__name__}'s policy is a table with no "
            "network (its values are in the model .zip)"
        )
    for what, space in (("observation", actor_observation_space(model)), ("action", model.action_space)):
        if not isinstance(space, spaces.Box | spaces.Discrete):
            raise TypeError(f"export supports Box and Discrete spaces; the {what} space is {space}")
