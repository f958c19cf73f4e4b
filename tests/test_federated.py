"""Federated homes (sbagents.federated): the homes' draws, a home's learner, FedProx's pull, DP-FedAvg's accounting,
what a home's reply carries, and whole runs: Flower's simulation (Ray) and a real deployment on localhost.

The parts without Flower run everywhere; the rest needs the ``private`` extra (Flower; its simulation needs Ray),
which ``.ci/run`` installs in the Ray venv with ``SBAGENTS_REQUIRE_FLOWER=1``, so that there a missing Flower fails
instead of skipping.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import socket
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_helpers import check_error, cli, run_main

from sbagents.federated.homes import PREFERENCE_RANGES, TASTES, client_homes, held_out_homes
from sbagents.federated.local import (
    BUFFER_FILE,
    MODEL_FILE,
    HomeLearner,
    add_proximal_term,
    home_experiment,
    load_shared_state,
    make_env,
    new_model,
    shared_state,
)
from sbagents.federated.settings import FederatedSettings

REQUIRED = bool(os.environ.get("SBAGENTS_REQUIRE_FLOWER"))
HAS_FLOWER = importlib.util.find_spec("flwr") is not None
HAS_RAY = importlib.util.find_spec("ray") is not None
needs_flower = pytest.mark.skipif(
    not HAS_FLOWER and not REQUIRED,
    reason="needs Flower: pip install -e '.[test,distributed,federated]' (.ci/run: the Ray venv)")
needs_simulation = pytest.mark.skipif(not (HAS_FLOWER and HAS_RAY) and not REQUIRED,
                                      reason="Flower's simulation needs Ray: the Ray venv of .ci/run")
#: Small and fast: 64-64 nets, learning after 100 steps.
TINY = {"learning_starts": 100, "batch_size": 32}
SMART = "sbagents/SmartHome-v0"


def tiny(**kwargs: object) -> FederatedSettings:
    base: dict[str, object] = dict(homes=2, rounds=2, local_steps=150, held_out=2, eval_episodes=1,
                                   hyperparams=dict(TINY))
    return FederatedSettings(**{**base, **kwargs})  # type: ignore[arg-type]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


# ---------------------------------------------------------------- bad input (one line, exit 2)
@pytest.mark.parametrize(("args", "message"), [
    (["--homes", "1"], "--homes must be >= 2"),
    (["--strategy", "fedsgd"], "--strategy 'fedsgd' does not exist; use one of fedavg, fedprox, dp-fedavg"),
    (["--algo", "dqn"], "federated homes train one of a2c, ppo, ddpg"),
    (["--env", "sbagents/GridWorld-v0"], "need an env with per-home users"),
    (["--rounds", "0"], "--rounds must be >= 1"),
    (["--strategy", "dp-fedavg", "--dp-noise", "0"], "--dp-noise must be > 0"),
    (["--dp-delta", "0.5"], "--dp-delta must be in (0, 1/8)"),
    (["--homes", "2", "--personalize", "2"], "--personalize 2: homes are 0..1"),
])
def test_bad_input_is_one_line(args: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = run_main("federated.__main__", *args)
    check_error(code, capsys.readouterr().err, message)


@pytest.mark.skipif(HAS_FLOWER, reason="Flower is installed here")
def test_without_flower_says_which_extra(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = run_main("federated.__main__", "--homes", "2", "-f", str(tmp_path))
    check_error(code, capsys.readouterr().err, "pip install 'sbagents[federated]'")
    assert not (tmp_path / "ddpg").exists()


# ---------------------------------------------------------------- homes
def test_client_homes_are_non_iid_and_held_out_homes_are_new() -> None:
    homes = client_homes(8, seed=3)
    assert [h.taste for h in homes] == list(TASTES) * 2
    for h in homes:
        (t_lo, t_hi), (l_lo, l_hi) = TASTES[h.taste]
        assert t_lo <= h.preferred_temp <= t_hi and l_lo <= h.preferred_light <= l_hi
    cool = [h.preferred_temp for h in homes if h.taste.startswith("cool")]
    warm = [h.preferred_temp for h in homes if h.taste.startswith("warm")]
    assert max(cool) < min(warm)  # no home sees the other tastes' users
    assert client_homes(8, seed=3) == homes and client_homes(8, seed=4) != homes
    held = held_out_homes(16, seed=3)
    (t_lo, t_hi), (l_lo, l_hi) = PREFERENCE_RANGES
    assert all(t_lo <= h.preferred_temp <= t_hi and l_lo <= h.preferred_light <= l_hi for h in held)
    assert not {(h.preferred_temp, h.preferred_light) for h in held} & {(h.preferred_temp, h.preferred_light)
                                                                       for h in homes}
    inside = [h for h in held if any(TASTES[t][0][0] <= h.preferred_temp <= TASTES[t][0][1]
                                     and TASTES[t][1][0] <= h.preferred_light <= TASTES[t][1][1] for t in TASTES)]
    assert len(inside) < len(held) / 2  # most held-out users are in no client's taste


def test_settings_travel_through_the_run_config() -> None:
    settings = tiny(strategy="fedprox", proximal_mu=0.1, hyperparams={"learning_starts": 100,
                                                                     "policy_kwargs": {"net_arch": [32, 32]}})
    flat = settings.to_run_config()
    assert all(isinstance(v, str | int | float | bool) for v in flat.values())
    assert FederatedSettings.from_run_config(flat) == settings


# ---------------------------------------------------------------- one home's learner
def test_exchanged_parameters_are_the_online_networks_and_are_checked() -> None:
    torch.set_num_threads(1)
    exp = home_experiment(tiny())
    model = new_model(exp, make_env(exp, 0), 0)
    state = shared_state(model)
    assert state and not any("_target" in k for k in state)
    assert set(state) == {k for k in model.policy.state_dict() if "_target." not in k}
    shifted = {k: v + 1.0 for k, v in state.items()}
    load_shared_state(model, shifted, sync_targets=True)
    full = model.policy.state_dict()
    for key, value in shifted.items():
        assert torch.equal(full[key], value)
        target = key.replace("actor.", "actor_target.", 1).replace("critic.", "critic_target.", 1)
        assert torch.equal(full[target], value)
    with pytest.raises(ValueError, match="names differ"):
        load_shared_state(model, dict(list(state.items())[1:]))
    wrong = dict(state)
    first = next(iter(wrong))
    wrong[first] = torch.zeros(3)
    with pytest.raises(ValueError, match="shape"):
        load_shared_state(model, wrong)


def test_fedprox_adds_the_proximal_gradient() -> None:
    torch.set_num_threads(1)
    exp = home_experiment(tiny())
    model = new_model(exp, make_env(exp, 0), 0)
    anchor = shared_state(model)
    with torch.no_grad():
        for p in model.policy.parameters():
            p.add_(0.5)
    hooks = add_proximal_term(model, anchor, mu=0.2)
    params = dict(model.policy.actor.named_parameters())
    for p in params.values():
        p.grad = torch.zeros_like(p)
    before = {k: p.detach().clone() for k, p in params.items()}
    model.policy.actor.optimizer.step()
    for name, p in params.items():  # the hook ran before the step: grad = 0 + mu (w - w_global)
        expected = 0.2 * (before[name] - anchor[f"actor.{name}"])
        assert torch.allclose(p.grad, expected)
    for hook in hooks:
        hook.remove()


def test_a_home_keeps_its_state_between_rounds(tmp_path: Path) -> None:
    settings = tiny()
    home = client_homes(2, 0)[1]
    exp = home_experiment(settings)
    global_state = shared_state(new_model(exp, make_env(exp, 0), 0))
    learner = HomeLearner(settings, home, tmp_path / "home-1")
    first = learner.train_round(global_state, 1)
    assert list(first) == list(global_state)
    assert all(first[k].shape == v.shape for k, v in global_state.items())
    assert any(not torch.equal(first[k], v) for k, v in global_state.items())  # it learned
    assert (tmp_path / "home-1" / MODEL_FILE).exists() and (tmp_path / "home-1" / BUFFER_FILE).exists()
    learner.train_round(first, 2)
    from stable_baselines3 import DDPG

    from sbagents.safe_load import load_model
    from sbagents.state_files import load_replay_buffer

    model = load_model(DDPG, tmp_path / "home-1" / MODEL_FILE, for_training=True)  # full-size buffer
    load_replay_buffer(model.replay_buffer, tmp_path / "home-1" / BUFFER_FILE)
    assert model.num_timesteps == 2 * settings.local_steps
    assert model.replay_buffer.size() == 2 * settings.local_steps  # the home's own experience, both rounds
    prefs = model.replay_buffer.observations[: model.replay_buffer.size(), 0, 3:]
    assert np.allclose(prefs, prefs[0])  # one user: this home's


# ---------------------------------------------------------------- DP-FedAvg's accounting
def test_dp_fedavg_epsilon_is_opacus_rdp_of_the_rounds() -> None:
    from opacus.accountants import RDPAccountant
    from opacus.accountants.analysis.rdp import compute_rdp, get_privacy_spent

    from sbagents.federated.strategies import dp_epsilon
    from sbagents.private.accounting import ORDERS

    settings = tiny(strategy="dp-fedavg", dp_noise=1.3, dp_delta=1e-3)
    assert dp_epsilon(tiny(), 5) is None and dp_epsilon(settings, 0) == 0.0
    for rounds in (1, 10, 50):
        rdp = compute_rdp(q=1.0, noise_multiplier=1.3, steps=rounds, orders=ORDERS)
        exact, _ = get_privacy_spent(orders=ORDERS, rdp=rdp, delta=1e-3)
        assert dp_epsilon(settings, rounds) == pytest.approx(exact, rel=1e-9)
        accountant = RDPAccountant()
        accountant.history = [(1.3, 1.0, rounds)]
        reference = accountant.get_epsilon(1e-3)
        assert reference <= dp_epsilon(settings, rounds)  # our orders are a subset: an upper bound
        if reference <= 10:  # orders below 2 matter only above ~11 (sbagents.private.accounting.ORDERS)
            assert dp_epsilon(settings, rounds) <= 1.03 * reference
    assert dp_epsilon(settings, 10) < dp_epsilon(settings, 50)


# ---------------------------------------------------------------- what leaves a home
def check_replies(run_dir: Path, homes: int, rounds: int, clip: float | None = None, first_trained: int = 1) -> None:
    """Every reply the server received held the home's parameters (the global names and shapes) and
    ``num-examples``, nothing else; with DP-FedAvg the update was clipped at home. Homes take gradient steps from
    round ``first_trained`` on (before it their update is zero)."""
    record = json.loads((run_dir / "federated.json").read_text())
    replies = record["replies"]
    assert len(replies) == homes * rounds
    assert sorted(Counter(r["round"] for r in replies).items()) == [(i, homes) for i in range(1, rounds + 1)]
    for reply in replies:
        assert "error" not in reply, reply
        assert reply["records"] == {"arrays": "ArrayRecord", "metrics": "MetricRecord"}
        assert reply["metric_keys"] == ["num-examples"] and reply["config_keys"] == []
        assert reply["same_names_and_shapes"]
        assert (reply["update_norm"] > 0) == (reply["round"] >= first_trained)
        if clip is not None:
            assert reply["update_norm"] <= clip * (1 + 1e-4)


@needs_flower
def test_a_deployed_home_may_set_its_own_user() -> None:
    from sbagents.federated.apps import home_of

    settings = tiny(homes=4)
    assert home_of(settings, {"partition-id": 2}) == client_homes(4, 0)[2]
    own = home_of(settings, {"home": 3, "preferred-temp": 22.5, "preferred-light": 61.0})
    assert (own.index, own.taste, own.preferred_temp, own.preferred_light) == (3, "own", 22.5, 61.0)


# ---------------------------------------------------------------- whole runs
def _run_dir(logs: Path, k: int = 1) -> Path:
    return logs / "ddpg" / f"sbagents_SmartHome-v0_{k}"


def _rounds(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / "rounds.csv").open(newline="") as f:
        return list(csv.DictReader(f))


@needs_simulation
@pytest.mark.slow  # Flower's simulation on Ray in a child process (~20 s here)
def test_simulation_two_homes_two_rounds_writes_a_normal_run_dir(tmp_path: Path,
                                                                 capfd: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    done = cli("federated.__main__", "--homes", "2", "--rounds", "2", "--local-steps", "150", "--held-out", "2",
               "--eval-episodes", "1", "--final-eval-episodes", "2", "--strategy", "fedprox", "-f", str(logs),
               "--personalize", "1", "--personal-steps", "200", "-params", "learning_starts:100", "batch_size:32")
    assert done.returncode == 0, done.stderr[-3000:]
    run_dir = _run_dir(logs)
    for name in ("sbagents_SmartHome-v0.zip", "vecnormalize.npz", "rounds.csv", "rounds.png", "federated.json",
                 "summary.json", "command.txt"):
        assert (run_dir / name).exists(), name
    rows = _rounds(run_dir)
    assert [int(r["round"]) for r in rows] == [0, 1, 2]
    assert all(0 <= float(r["heldout_criterion_share"]) <= 1 for r in rows)
    check_replies(run_dir, homes=2, rounds=2)
    record = json.loads((run_dir / "federated.json").read_text())
    assert int(rows[1]["bytes_up_per_home"]) == record["bytes_per_round_per_home"] // 2 > 4 * record["parameters"]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["federated"]["strategy"] == "fedprox" and summary["federated"]["rounds"] == 2
    assert summary["n_timesteps"] == 2 * 2 * 150 and summary["eval"]["n_episodes"] == 2
    # the round lines come from the simulation's own (spawned) process, on file descriptor 1: capfd has them
    assert "round 2/2" in capfd.readouterr().out and "personalized: comfort" in done.stdout
    personal = json.loads((_run_dir(logs, 2) / "summary.json").read_text())["personalization"]
    assert personal["home"]["index"] == 1 and set(personal["before"]) == set(personal["after"])
    # evaluate and export take the federated run dir as any other
    evaluated = cli("evaluate", "--algo", "ddpg", "--env", SMART, "-f", str(logs), "--exp-id", "1", "-n", "2",
                    "--json")
    assert evaluated.returncode == 0, evaluated.stderr[-2000:]
    assert json.loads(evaluated.stdout.strip().splitlines()[-1])["n_episodes"] == 2
    exported = cli("export", "--algo", "ddpg", "--env", SMART, "-f", str(logs), "--exp-id", "1")
    assert exported.returncode == 0, exported.stderr[-2000:]
    assert (run_dir / "export" / "policy.onnx").exists()


@needs_simulation
@pytest.mark.slow  # Flower's simulation on Ray in a child process (~20 s here)
def test_simulation_dp_fedavg_reports_its_epsilon(tmp_path: Path) -> None:
    from sbagents.federated.strategies import dp_epsilon

    # learning starts in round 2: round 1's updates are zero (Flower's clipping mod divides by their norm)
    done = cli("federated.__main__", "--homes", "2", "--rounds", "2", "--local-steps", "150", "--held-out", "1",
               "--eval-episodes", "1", "--final-eval-episodes", "0", "--strategy", "dp-fedavg", "--dp-clip", "0.5",
               "--dp-noise", "1.0", "-f", str(tmp_path), "-params", "learning_starts:200", "batch_size:32")
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((_run_dir(tmp_path) / "summary.json").read_text())
    expected = dp_epsilon(FederatedSettings(strategy="dp-fedavg", dp_noise=1.0, homes=2), 2)
    assert summary["federated"]["dp_epsilon"] == pytest.approx(expected)
    check_replies(_run_dir(tmp_path), homes=2, rounds=2, clip=0.5, first_trained=2)
    assert "privacy: user-level epsilon" in done.stdout


@needs_flower
@pytest.mark.slow  # a server and two homes in their own interpreters (~60 s here)
def test_deployment_on_localhost_end_to_end(tmp_path: Path) -> None:
    port = free_port()
    logs = tmp_path / "logs"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    # subprocesses on purpose: a real deployment, one server and two homes talking over localhost
    server = subprocess.Popen(
        [sys.executable, "-m", "sbagents.federated", "--deploy", "--port", str(port), "--homes", "2", "--rounds",
         "2", "--local-steps", "150", "--held-out", "1", "--eval-episodes", "1", "--final-eval-episodes", "2",
         "-f", str(logs), "-params", "learning_starts:100", "batch_size:32"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    homes = [subprocess.Popen(
        [sys.executable, "-m", "sbagents.federated.home", "--home", str(i), "--superlink", f"127.0.0.1:{port}",
         "--port", str(free_port()), "--state-dir", str(tmp_path / f"home-{i}"), "--wait", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for i in range(2)]
    try:
        out, err = server.communicate(timeout=400)
        assert server.returncode == 0, err[-3000:] + out[-2000:]
        for home in homes:  # the homes stop by themselves once the server has gone
            h_out, h_err = home.communicate(timeout=60)
            assert home.returncode == 0, h_err[-2000:]
            assert "the server has gone" in h_out
    finally:
        for proc in (server, *homes):
            if proc.poll() is None:
                proc.kill()
    run_dir = _run_dir(logs)
    assert [int(r["round"]) for r in _rounds(run_dir)] == [0, 1, 2]
    assert "round 2/2" in out and (run_dir / "sbagents_SmartHome-v0.zip").exists()
    assert json.loads((run_dir / "summary.json").read_text())["eval"]["n_episodes"] == 2
    check_replies(run_dir, homes=2, rounds=2)
    for i in range(2):  # each home's experience stayed in its own folder
        assert (tmp_path / f"home-{i}" / f"home-{i}" / BUFFER_FILE).exists()


@needs_flower
def test_deployment_port_in_use_and_no_server_are_one_line(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = cli("federated.__main__", "--deploy", "--port", str(port), "--homes", "2", "-f", str(tmp_path))
        check_error(done.returncode, done.stderr, f"--port {port}: cannot listen on 127.0.0.1:{port}")
        assert not (tmp_path / "ddpg").exists()  # checked before a run dir exists
        home = cli("federated.home", "--home", "0", "--port", str(port), "--superlink", "127.0.0.1:1")
        check_error(home.returncode, home.stderr, f"--port {port}: cannot listen on 127.0.0.1:{port}")
    nobody = cli("federated.home", "--home", "0", "--superlink", f"127.0.0.1:{free_port()}", "--wait", "1")
    check_error(nobody.returncode, nobody.stderr, "no server at")
    bad = cli("federated.home", "--home", "0", "--superlink", "localhost")
    check_error(bad.returncode, bad.stderr, "expected HOST:PORT")


def test_every_home_and_the_server_scale_users_from_the_population_ranges() -> None:
    exp = home_experiment(tiny())
    home = make_env(exp, 0)
    other = make_env(home_experiment(tiny(), env_kwargs=client_homes(2, 0)[1].env_kwargs()), 5)
    for venv in (home, other):
        rms = venv.obs_rms  # type: ignore[attr-defined]
        assert np.allclose(rms.mean[3:], [23.0, 65.0]) and np.allclose(np.sqrt(rms.var[3:]), [3.0, 15.0])
        assert np.allclose(rms.mean[:2], [23.0, 50.0])  # the state from its bounds, as under DP
        assert not venv.training  # type: ignore[attr-defined]  # fixed: never computed from a home's data
