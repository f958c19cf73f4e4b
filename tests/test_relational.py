"""The relational features extractors: ``PairwiseDistanceFeatures`` (the distances it appends, its checks) and
``EntityAttentionFeatures`` (shapes, invariance to the order of targets and of other agents, its checks), and the
shipped simple_spread entry that uses the latter (trains, evaluates with the team metrics, exports with ONNX
parity)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sbagents.core.zoo_config import default_config_path, lookup_entry
from sbagents.multiagent.relational import EntityAttentionFeatures, PairwiseDistanceFeatures
from tests.cli_helpers import cli

SPREAD_OBS = spaces.Box(-np.inf, np.inf, (18,), np.float32)  # simple_spread, N=3


def test_distances_of_every_target_to_the_observer_and_each_other_agent() -> None:
    extractor = PairwiseDistanceFeatures(SPREAD_OBS, targets=[4, 10], agents=[10, 14])
    assert extractor.features_dim == 18 + 3 * 3
    obs = np.zeros((2, 18), dtype=np.float32)
    obs[0, 4:10] = [3, 4, 0, 1, -1, 0]  # landmarks at (3, 4), (0, 1), (-1, 0) relative to the observer
    obs[0, 10:14] = [3, 0, 0, 1]  # the other two agents at (3, 0) and (0, 1)
    features = extractor(th.as_tensor(obs)).numpy()
    assert features.shape == (2, 27)
    np.testing.assert_array_equal(features[:, :18], obs)  # the observation is kept as it is
    expected = [[5, 4, np.hypot(3, 3)],  # landmark 0: to me, to agent (3, 0), to agent (0, 1)
                [1, np.hypot(3, 1), 0],  # landmark 1 sits on the second other agent
                [1, 4, np.hypot(1, 1)]]
    np.testing.assert_allclose(features[0, 18:].reshape(3, 3), expected, rtol=1e-6)
    np.testing.assert_array_equal(features[1, 18:], np.zeros(9))  # everything at the origin


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"targets": [4, 9]}, "even-length"),
        ({"targets": [10, 4]}, "non-empty"),
        ({"agents": [10, 20]}, "inside the observation's 18 values"),
        ({"agents": [10]}, "two integers"),
        ({"targets": [4.0, 10]}, "two integers"),
    ],
)
def test_bad_ranges_are_one_clear_error(kwargs: dict[str, list[float]], message: str) -> None:
    with pytest.raises(ValueError, match=message) as info:
        PairwiseDistanceFeatures(SPREAD_OBS, **kwargs)  # type: ignore[arg-type]
    assert "\n" not in str(info.value)


def test_a_non_flat_space_is_refused() -> None:
    with pytest.raises(ValueError, match="flat Box"):
        PairwiseDistanceFeatures(spaces.Box(0, 1, (3, 6), np.float32))


def _spread_batch(rng: np.random.Generator, batch: int = 64) -> np.ndarray:
    obs = rng.uniform(-1.5, 1.5, (batch, 18)).astype(np.float32)
    obs[:, 14:] = 0.0  # the silent agents' communication
    return obs


def test_attention_features_ignore_the_order_of_targets_and_of_other_agents() -> None:
    th.manual_seed(0)
    extractor = EntityAttentionFeatures(SPREAD_OBS, targets=[4, 10], agents=[10, 14], own=[0, 4], hidden=8, heads=3)
    assert extractor.features_dim == 4 + 3 * 8 + 2 * 8
    obs = _spread_batch(np.random.default_rng(0))
    shuffled = obs.copy()
    shuffled[:, 4:10] = obs[:, 4:10].reshape(-1, 3, 2)[:, [2, 0, 1]].reshape(-1, 6)  # landmarks reordered
    shuffled[:, 10:14] = obs[:, 10:14].reshape(-1, 2, 2)[:, [1, 0]].reshape(-1, 4)  # other agents swapped
    with th.no_grad():
        features, features_shuffled = extractor(th.as_tensor(obs)), extractor(th.as_tensor(shuffled))
    assert features.shape == (64, 44)
    th.testing.assert_close(features, features_shuffled, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(features[:, :4].numpy(), obs[:, :4])  # own features pass through
    moved = obs.copy()
    moved[:, 4] += 0.5  # one landmark moves: the features change
    with th.no_grad():
        assert not th.allclose(extractor(th.as_tensor(moved)), features)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"own": [3, 30]}, "own must be"), ({"own": [3]}, "own must be"), ({"hidden": 0}, "hidden and heads"),
     ({"heads": 1.5}, "hidden and heads"),
     ({"agents": [10, 15]}, "EntityAttentionFeatures: agents .* even-length")],
)
def test_attention_features_refuse_bad_settings(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message) as info:
        EntityAttentionFeatures(SPREAD_OBS, **kwargs)  # type: ignore[arg-type]
    assert "\n" not in str(info.value)


def test_the_shipped_spread_entry_uses_it() -> None:
    entry = lookup_entry(default_config_path("ppo"), "mpe2.simple_spread_v3")
    kwargs = entry["policy_kwargs"]
    assert kwargs["features_extractor_class"].endswith("relational:EntityAttentionFeatures")
    assert kwargs["features_extractor_kwargs"]["targets"] == [4, 10]
    assert kwargs["features_extractor_kwargs"]["agents"] == [10, 14]


def test_a_spread_run_with_it_evaluates_and_exports(tmp_path: Path) -> None:
    train = cli("train", "--algo", "ppo", "--env", "mpe2.simple_spread_v3", "-n", "2000", "-f", str(tmp_path),
                "--eval-freq", "0", "--final-eval-episodes", "0",
                "-params", "n_envs:4", "n_steps:25", "batch_size:100", "n_epochs:1")
    assert train.returncode == 0, train.stderr
    evaluated = cli("evaluate", "--algo", "ppo", "--env", "mpe2.simple_spread_v3", "-f", str(tmp_path), "-n", "3",
                    "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    assert '"landmarks_covered"' in evaluated.stdout  # the env's team metrics reach the summary
    exported = cli("export", "--algo", "ppo", "--env", "mpe2.simple_spread_v3", "-f", str(tmp_path))
    assert exported.returncode == 0, exported.stderr
    assert "max abs action difference 0.00e+00" in exported.stdout
