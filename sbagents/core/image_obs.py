"""Pixel observations without a zoo entry of their own: never an MLP on raw images.

An env that observes images (``uint8`` Boxes ``(H, W)`` or ``(H, W, 1|3|4)``; for a PettingZoo env, every agent's)
and whose hyperparameters come from a fallback entry (``default``, ``pettingzoo``) with ``MlpPolicy`` would train an
MLP on raw pixels (``pettingzoo.butterfly.pistonball_v6``: 20 agents x 457 x 120 x 3 bytes per step, a 13.5 GB
rollout buffer at the default budget). Instead:

- on-policy algorithms with a ``CnnPolicy`` (ppo, a2c, trpo) get the project's image recipe: grayscale 84 x 84
  frames (:class:`~sbagents.multiagent.preprocessing.ImagePreprocessing` for PettingZoo envs, SB3's ``WarpFrame``
  for Gymnasium envs), 4 stacked (``frame_stack``) and ``CnnPolicy``, written into the run's ``config.yml``;
- other algorithms (replay buffers of images need an entry that sizes them) are refused in one line naming the
  options to set.

An entry of the env's own, or ``-params policy:...``, is taken as it is.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gymnasium import spaces

from sbagents.algos import ALGOS
from sbagents.core.env_kinds import PETTINGZOO_DEFAULT_ENTRY
from sbagents.core.env_names import EnvRef
from sbagents.core.options import TrainSpec
from sbagents.core.zoo_config import default_config_path, entry_name
from sbagents.errors import UsageError

#: Entries that serve envs without one of their own.
FALLBACK_ENTRIES = frozenset({"default", PETTINGZOO_DEFAULT_ENTRY})
#: The preprocessing wrappers an image env without an entry gets (as a zoo entry's ``env_wrapper``).
FRAME_STACK = 4


def is_image_space(space: Any) -> bool:
    """Whether ``space`` is an image: a ``uint8`` Box ``(H, W)`` or ``(H, W, C)`` with ``C`` in 1, 3, 4."""
    if not isinstance(space, spaces.Box) or space.dtype.name != "uint8":
        return False
    return len(space.shape) == 2 or (len(space.shape) == 3 and space.shape[2] in (1, 3, 4))


def observation_spaces(ref: EnvRef, env_kwargs: dict[str, Any]) -> list[Any] | None:
    """The observation space of every agent (one for a Gymnasium env) of one env built with ``env_kwargs``; None
    when it cannot be built here (the env checks that follow then report why)."""
    try:
        return ref.kind.observation_spaces(ref, env_kwargs)
    except Exception:  # noqa: BLE001 - bad kwargs, a missing dependency: reported by the env checks that follow
        return None


def _uses_fallback(spec: TrainSpec, ref: EnvRef, entry: dict[str, Any]) -> bool:
    """Whether ``entry`` came from a fallback entry with ``MlpPolicy`` that nobody chose for this env."""
    if "policy" in spec.hyperparams or entry.get("policy", "MlpPolicy") != "MlpPolicy":
        return False
    path = Path(spec.conf_file) if spec.conf_file is not None else default_config_path(spec.algo)
    name = entry_name(path, ref.config_keys)
    return (name is None or name in FALLBACK_ENTRIES) and not entry.get("env_wrapper")


def image_entry(spec: TrainSpec, ref: EnvRef, entry: dict[str, Any]) -> dict[str, Any]:
    """``entry`` with the image recipe (module docstring) when ``ref`` observes images and ``entry`` is a fallback
    with ``MlpPolicy``; ``entry`` itself otherwise.

    :raises UsageError: (one line) such an env with an algorithm the recipe does not fit.
    """
    wrapper = ref.kind.image_wrapper
    if wrapper is None or not _uses_fallback(spec, ref, entry):
        return entry
    found = observation_spaces(ref, dict(entry.get("env_kwargs") or {}))
    if not found or not all(is_image_space(space) for space in found):
        return entry
    algo = ALGOS[spec.algo]
    if algo.off_policy or "CnnPolicy" not in getattr(algo.cls, "policy_aliases", {}):
        raise UsageError(
            f"{ref.env_id} observes images {tuple(found[0].shape)} and has no zoo entry of its own, so {spec.algo} "
            f"would train an MLP on raw pixels; give it an entry with policy: CnnPolicy, env_wrapper (image "
            "preprocessing), frame_stack and buffer_size (see cooperative_pong_v6 in zoo_configs/ppo.yml), train "
            "ppo or a2c (they get that recipe), or pass -params policy:MlpPolicy to insist")
    return {**entry, "policy": "CnnPolicy", "env_wrapper": [wrapper],
            "frame_stack": entry.get("frame_stack") or FRAME_STACK}
