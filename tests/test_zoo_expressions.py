"""RL Zoo's Python-expression strings (``policy_kwargs: "dict(...)"``) are accepted as they are and read as data:
nothing in them runs, anything but data is one clear line."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch.nn as nn
from cli_helpers import check_error, run_main

from sbagents.core.experiment import resolve
from sbagents.core.zoo_config import MAX_EXPRESSION_CHARS, default_config_path, lookup_entry, python_literal
from sbagents.errors import UsageError

RL_ZOO_POLICY_KWARGS = """dict(
                    ortho_init=False,
                    activation_fn=nn.ReLU,
                    lstm_hidden_size=64,
                    enable_critic_lstm=True,
                    net_arch=dict(pi=[64], vf=[64])
                  )"""


def test_rl_zoos_policy_kwargs_string_is_read_as_data() -> None:
    assert python_literal(RL_ZOO_POLICY_KWARGS, "policy_kwargs") == {
        "ortho_init": False, "activation_fn": "nn.ReLU", "lstm_hidden_size": 64, "enable_critic_lstm": True,
        "net_arch": {"pi": [64], "vf": [64]}}
    assert python_literal("{'norm_obs': True, 'norm_reward': False, 'clip_obs': -1.5e1}", "normalize") == {
        "norm_obs": True, "norm_reward": False, "clip_obs": -15.0}
    assert python_literal("dict(net_arch=[dict(pi=[8], vf=[8])], log_std_init=-2, x=(1, None))", "k") == {
        "net_arch": [{"pi": [8], "vf": [8]}], "log_std_init": -2, "x": [1, None]}


def test_the_shipped_ppo_lstm_entry_builds_the_policy_rl_zoo_describes() -> None:
    entry = lookup_entry(default_config_path("ppo_lstm"), "sbagents/CartPoleNoVel-v1")
    assert isinstance(entry["policy_kwargs"], str)  # as RL Zoo writes it
    exp = resolve("ppo_lstm", "sbagents/CartPoleNoVel-v1", entry, "ppo_lstm.yml")
    kwargs = exp.algo_kwargs["policy_kwargs"]
    assert kwargs["activation_fn"] is nn.ReLU and kwargs["lstm_hidden_size"] == 64
    assert kwargs["net_arch"] == {"pi": [64], "vf": [64]} and exp.normalize is True


@pytest.mark.parametrize("text", [
    "dict(a=__import__('os').system('true'))",
    "__import__('os')",
    "dict(a=open('/etc/passwd'))",
    "dict(a=lambda: 1)",
    "dict(a=[1][0])",
    "dict(a=1 + 1)",
    "dict(**{'a': 1})",
    "{**{'a': 1}}",
    "dict([('a', 1)])",
    "dict(a=b'bytes')",
    "dict(a=f'{1}')",
    "dict(a=(yield))",
    "dict(a=",
])
def test_anything_but_data_is_refused_in_one_line(text: str) -> None:
    with pytest.raises(UsageError) as info:
        python_literal(text, "policy_kwargs (test)")
    message = str(info.value)
    assert "\n" not in message and message.startswith("policy_kwargs (test)") and "accepted" in message


def test_huge_or_deep_expressions_are_refused() -> None:
    with pytest.raises(UsageError, match=f"at most {MAX_EXPRESSION_CHARS}"):
        python_literal("dict(a=[" + "1," * 3000 + "])", "k")
    with pytest.raises(UsageError, match="nested"):
        python_literal("[" * 2000 + "]" * 2000, "k")


def test_the_cli_takes_an_expression_override_and_refuses_code(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    common = ("train", "--algo", "ppo", "--env", "CartPole-v1", "-n", "64", "-f", str(tmp_path), "--verbose", "0",
              "--eval-freq", "-1", "--final-eval-episodes", "0")
    assert run_main(*common, "-params", "n_steps:32", "batch_size:32", "policy_kwargs:dict(net_arch=[8])") == 0
    capsys.readouterr()
    code = run_main(*common, "-params", "policy_kwargs:dict(net_arch=__import__('os').getcwd())")
    check_error(code, capsys.readouterr().err, "is not data")
