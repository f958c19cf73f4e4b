"""Zoo config parsing: safe YAML, lookup order, overrides, validation of keys and values."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch.nn as nn
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.utils import LinearSchedule

from sbagents.core.env_kinds import GAME, PETTINGZOO_DEFAULT_ENTRY, SINGLE_AGENT, TEAM, EnvKind
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import resolve
from sbagents.core.selfplay_options import SelfPlayOptions
from sbagents.core.zoo_config import lookup_entry, parse_overrides
from sbagents.errors import UsageError

GRID = "sbagents/GridWorld-v0"


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "conf.yml"
    path.write_text(text)
    return path


def test_overrides_are_yaml_values() -> None:
    parsed = parse_overrides(
        ["learning_rate:3e-4", "n_envs:8", "policy_kwargs:{net_arch: [64, 64]}", "train_freq:[1, episode]",
         "normalize:true", "policy:MlpPolicy"]
    )
    assert parsed == {
        "learning_rate": 3e-4, "n_envs": 8, "policy_kwargs": {"net_arch": [64, 64]},
        "train_freq": [1, "episode"], "normalize": True, "policy": "MlpPolicy",
    }


def test_code_in_overrides_stays_a_string_and_is_rejected_where_a_number_is_needed() -> None:
    payload = "__import__('os').system('touch /tmp/sbagents_pwned')"
    parsed = parse_overrides([f"learning_rate:{payload}"])
    assert parsed["learning_rate"] == payload
    with pytest.raises(UsageError, match="learning_rate must be a number"):
        resolve("dqn", GRID, {"n_timesteps": 10, **parsed}, "cli")
    assert not Path("/tmp/sbagents_pwned").exists()


def test_python_tags_are_rejected(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="not a YAML scalar"):
        parse_overrides(["policy_kwargs:!!python/object/apply:os.system ['echo pwned']"])
    path = write(tmp_path, "default:\n  n_timesteps: !!python/object/apply:os.system ['echo pwned']\n")
    with pytest.raises(UsageError, match="malformed YAML"):
        lookup_entry(path, GRID)


@pytest.mark.parametrize("bad", ["learning_rate", ":3", "learning_rate:[1,"])
def test_malformed_overrides(bad: str) -> None:
    with pytest.raises(UsageError, match="-params"):
        parse_overrides([bad])


def test_scientific_notation_without_dot(tmp_path: Path) -> None:
    path = write(tmp_path, "default:\n  n_timesteps: 1e6\n  learning_rate: 3e-4\n")
    assert lookup_entry(path, GRID) == {"n_timesteps": 1e6, "learning_rate": 3e-4}
    exp = resolve("dqn", GRID, lookup_entry(path, GRID), "f")
    assert exp.n_timesteps == 1_000_000 and isinstance(exp.n_timesteps, int)


def test_lookup_order(tmp_path: Path) -> None:
    text = "atari:\n  n_timesteps: 2\ndefault:\n  n_timesteps: 3\nsbagents/GridWorld-v0:\n  n_timesteps: 1\n"
    path = write(tmp_path, text)
    assert lookup_entry(path, GRID)["n_timesteps"] == 1
    assert lookup_entry(path, "PongNoFrameskip-v4", atari=True)["n_timesteps"] == 2
    assert lookup_entry(path, "CartPole-v1")["n_timesteps"] == 3


def test_missing_entry_without_default(tmp_path: Path) -> None:
    path = write(tmp_path, "CartPole-v1:\n  n_timesteps: 2\n")
    with pytest.raises(UsageError, match=r"no entry for 'sbagents/GridWorld-v0' and no 'default'.*CartPole-v1"):
        lookup_entry(path, GRID)


def test_malformed_yaml_names_file_and_line(tmp_path: Path) -> None:
    path = write(tmp_path, "default:\n  n_timesteps: 10\n  policy: [unclosed\n")
    with pytest.raises(UsageError, match=rf"malformed YAML in {path} line \d+"):
        lookup_entry(path, GRID)


def test_unknown_hyperparameter_lists_accepted() -> None:
    with pytest.raises(UsageError, match=r"unknown hyperparameter\(s\) learnin_rate.*accepted: .*learning_rate"):
        resolve("dqn", GRID, {"n_timesteps": 10, "learnin_rate": 1e-3}, "cli")


def test_conversions() -> None:
    exp = resolve(
        "ppo", GRID,
        {"n_timesteps": 100, "n_envs": 4, "learning_rate": "lin_3e-4", "clip_range": 0.2,
         "policy_kwargs": {"net_arch": [64, 64], "activation_fn": "tanh", "optimizer_class": "AdamW"},
         "normalize": {"norm_reward": False}},
        "cli",
    )
    assert isinstance(exp.algo_kwargs["learning_rate"], LinearSchedule)
    assert exp.algo_kwargs["learning_rate"](1.0) == pytest.approx(3e-4)
    assert exp.algo_kwargs["policy_kwargs"]["activation_fn"] is nn.Tanh
    assert exp.n_envs == 4 and exp.normalize == {"norm_reward": False}
    sac = resolve("sac", "Pendulum-v1", {"n_timesteps": 1, "replay_buffer_class": "HerReplayBuffer",
                                          "train_freq": [1, "episode"]}, "cli")
    assert sac.algo_kwargs["replay_buffer_class"] is HerReplayBuffer
    assert sac.algo_kwargs["train_freq"] == (1, "episode")


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"n_envs": 0}, "n_envs must be a positive integer"),
        ({"policy_kwargs": "net_arch=[64]"}, "policy_kwargs must be a mapping"),
        ({"noise_type": "pink"}, "noise_type must be"),
        ({"env_wrapper": "no.such.Module"}, "outside the import allow-list"),
        ({"env_wrapper": "sbagents.no_such.Module"}, "cannot import env_wrapper"),
        ({"learning_rate": "lin_x"}, "not a linear schedule"),
    ],
)
def test_invalid_values(entry: dict[str, object], message: str) -> None:
    with pytest.raises(UsageError, match=message):
        resolve("td3", "Pendulum-v1", {"n_timesteps": 1, **entry}, "cli")


def test_shipped_configs_parse() -> None:
    root = Path(__file__).resolve().parents[1] / "zoo_configs"
    for path in sorted(root.glob("*.yml")):
        algo = path.stem
        if algo.startswith("rllib_"):
            continue  # Ray RLlib entries (--backend rllib), checked in tests/test_rllib.py
        from sbagents.core.zoo_config import load_yaml

        for env_id, entry in load_yaml(path).items():
            game = env_id not in ("default", "atari", PETTINGZOO_DEFAULT_ENTRY) and resolve_env(env_id).kind is GAME
            kind = GAME if game else TEAM if _is_pettingzoo_entry(env_id) else SINGLE_AGENT
            exp = resolve(algo, env_id, dict(entry), str(path), kind)
            assert exp.n_timesteps > 0, (path, env_id)
            assert isinstance(exp.kind_options, SelfPlayOptions) == game, (path, env_id)


def _is_pettingzoo_entry(key: str) -> bool:
    """Whether a zoo-config key names a PettingZoo env (or is the entry every PettingZoo env gets)."""
    if key in ("default", "atari"):
        return False
    return key == PETTINGZOO_DEFAULT_ENTRY or resolve_env(key).kind is TEAM


@pytest.mark.parametrize(("kind", "key", "message"), [
    (SINGLE_AGENT, {"policies": "shared"}, "policies apply to PettingZoo envs only"),
    (SINGLE_AGENT, {"self_play": {}}, "self_play applies to turn-based games only"),
    (GAME, {"critic": "local"}, "critic apply to PettingZoo envs only"),
    (TEAM, {"self_play": {}}, "self_play applies to turn-based games only"),
    (TEAM, {"monitor_kwargs": {}}, "monitor_kwargs apply to Gymnasium envs only"),
])
def test_each_env_kind_refuses_the_keys_of_another(kind: EnvKind, key: dict[str, object], message: str) -> None:
    with pytest.raises(UsageError, match=message):
        resolve("ppo", GRID, {"n_timesteps": 10, **key}, "cli", kind)
