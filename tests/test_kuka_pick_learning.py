"""Learning the grasping pick-and-place: the HER config pair, the learning-speed benchmark, the ``pick`` command."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
import torch
from stable_baselines3 import HerReplayBuffer

from benchmarks.learning import kuka_curves, kuka_learning
from benchmarks.speed import learning_speed
from sbagents.core.experiment import resolve
from sbagents.core.zoo_config import load_yaml

CONF = learning_speed.CONFIG
OURS, PANDA = learning_speed.OURS, learning_speed.PANDA


def test_pick_pair_shares_its_hyperparameters() -> None:
    data = load_yaml(CONF)
    assert set(data) == {OURS, PANDA, "sbagents/RobustKukaPickAndPlace-v0"}  # the robust env: kuka-pick-demos
    assert data[OURS] == data[PANDA] == data["sbagents/RobustKukaPickAndPlace-v0"]  # no env_kwargs: panda-gym's
    # workspace is both envs' default
    exp = resolve("sac", OURS, dict(data[OURS]), "kuka_pick.yml")
    assert exp.n_timesteps == 500_000 and exp.n_envs == 2 and exp.policy == "MultiInputPolicy"
    assert exp.algo_kwargs["replay_buffer_class"] is HerReplayBuffer
    assert exp.algo_kwargs["policy_kwargs"]["net_arch"] == [64, 64]


def test_variants_gradient_steps_per_env_step() -> None:
    entry = load_yaml(CONF)[OURS]
    utd = {v.name: v.utd(entry) for v in learning_speed.VARIANTS}
    assert utd["SB3 default nets 256-256, 1 env"] == 1.0 and utd["64-64, 1 env"] == 1.0
    assert utd["64-64, 2 envs (shipped)"] == 0.5
    assert utd["64-64, 4 envs, 2 gradient steps"] == 0.5
    assert utd["64-64, 1 env, train_freq 2"] == 0.5


def test_learning_rate_is_measured_after_the_warm_up() -> None:
    torch.set_num_threads(1)
    entry = {k: v for k, v in load_yaml(CONF)[OURS].items() if k != "n_timesteps"}
    variant = learning_speed.Variant("tiny", overrides={"n_envs": 1, "learning_starts": 50, "batch_size": 32})
    assert learning_speed.learning_steps_per_second(OURS, entry, variant, 40) > 0


def test_table_reports_ratios_to_the_first_variant() -> None:
    names = [v.name for v in learning_speed.VARIANTS]
    rates = {OURS: {"env": 1000.0, **{name: 50.0 * (i + 1) for i, name in enumerate(names)}}}
    text = learning_speed.table(rates, learning_speed.utd_by_variant())
    rows = {r.split("|")[1].strip(): r for r in text.splitlines()[2:]}
    assert "| 1000 |" in rows["env alone, random actions"]
    assert "100 (2.00x)" in rows[names[1]] and "| 0.5 |" in rows["64-64, 2 envs (shipped)"]


def test_pick_command_checkpoints_with_the_replay_buffer(tmp_path: Path) -> None:
    task = kuka_learning.TASKS["kuka-pick-learning"]
    args = kuka_learning.build_parser(task.section).parse_args(["--panda-python", "python", "-f", str(tmp_path)])
    assert args.n_timesteps == 500_000 and args.conf == task.conf and args.pairs == ["pick"]
    cmd = kuka_learning._train_cmd("python", "sac", OURS, args, [])
    assert cmd[cmd.index("--save-freq") + 1] == "50000" and "--save-replay-buffer" in cmd
    no_checkpoints = argparse.Namespace(**{**vars(args), "save_freq": 0})
    assert "--save-freq" not in kuka_learning._train_cmd("python", "sac", OURS, no_checkpoints, [])
    entries = kuka_learning.pair_config(args.conf, task.pairs["pick"], tmp_path / "config.yml")
    assert set(load_yaml(tmp_path / "config.yml")) == {OURS, PANDA} == set(entries)
    command = f"python -m sbagents.train -conf {tmp_path}/pick/config.yml -f {tmp_path}/pick"
    assert kuka_curves.portable(command, tmp_path) == (
        "python -m sbagents.train -conf <output dir>/pick/config.yml -f <output dir>/pick")


def test_section_names_its_command_and_settings() -> None:
    names = [v.name for v in learning_speed.VARIANTS]
    rates = {OURS: {"env": 1000.0, **dict.fromkeys(names, 100.0)}, PANDA: {"env": 500.0, **dict.fromkeys(names, 50.0)}}
    results = {"command": "python -m benchmarks run learning-speed --panda --steps 10", "steps": 10, "rounds": 1,
               "utd": learning_speed.utd_by_variant(), "rates": rates}
    text = learning_speed.markdown(results)
    assert "`<panda-gym venv>/bin/python -m benchmarks run learning-speed --panda --steps 10`" in text
    assert "10 timed learning steps" in text and "median of 1 interleaved rounds" in text
    assert f"{PANDA} steps/s" in text and "| 50 (1.00x) |" in text


def test_report_option_takes_the_note_and_hides_the_log_folder(tmp_path: Path) -> None:
    import json

    import numpy as np

    run_dir = tmp_path / "runs" / "ours"
    run_dir.mkdir(parents=True)
    np.savez(run_dir / "evaluations.npz", timesteps=np.array([1000]), results=-np.ones((1, 2)),
             ep_lengths=np.full((1, 2), 50), successes=np.array([[True, False]]))
    (run_dir / "summary.json").write_text(json.dumps({"algo": "sac", "env": OURS, "n_timesteps": 1000}))
    (run_dir / "command.txt").write_text(f"python -m sbagents.train -f {tmp_path / 'runs'}")
    results = kuka_learning.run_task("kuka-pick-learning", ["--report", f"ours={run_dir}", "--log-folder",
                                                            str(tmp_path / "runs"), "--plots", str(tmp_path)])
    text = kuka_learning.render(results)
    assert kuka_learning.PICK_NOTE.strip() in text and "-f <output dir>`" in text and str(tmp_path) not in text
    assert "| 1000 | 50 |" in text and (tmp_path / "kuka_pick_learning.png").exists()
    assert results["commands"] == ["python -m benchmarks run kuka-pick-learning --report ours=<output dir>/ours "
                                   "--log-folder <output dir>"]


def test_in_hand_config_trains_with_the_aid_and_evaluates_the_plain_task() -> None:
    from sbagents.core.env_names import resolve_env
    from sbagents.env_factory import make_eval_vec, make_vec

    path = CONF.parent / "kuka_pick_in_hand.yml"
    entry = load_yaml(path)[OURS]
    plain = load_yaml(CONF)[OURS]
    differs = {k for k in set(entry) | set(plain) if entry.get(k) != plain.get(k)}
    assert differs == {"env_kwargs", "eval_env_kwargs"}  # otherwise the like-for-like entry
    exp = resolve("sac", OURS, dict(entry), path.name)
    ref = resolve_env(OURS)
    train, evaluation = make_vec(exp, ref, 1, 0), make_eval_vec(exp, ref, 1, 0)
    assert train.get_attr("start_in_hand") == [0.5] and evaluation.get_attr("start_in_hand") == [0.0]
    train.close()
    evaluation.close()


def test_each_pair_plots_beside_the_others() -> None:
    """One PNG per pair (the dense pair's beside the HER pair's), so a pair run alone never overwrites another's."""
    plots = {key: pair.plot for task in kuka_learning.TASKS.values() for key, pair in task.pairs.items()}
    assert plots["her"] == "kuka_learning_random.png" and plots["dense"] == "kuka_learning_random_dense.png"
    assert len(set(plots.values())) == len(plots)


def test_learning_speed_run_records_its_command_and_renders(monkeypatch: pytest.MonkeyPatch) -> None:
    """``run`` (the measuring replaced by fixed rates) returns what ``markdown`` turns into one row per variant."""
    names = [v.name for v in learning_speed.VARIANTS]
    monkeypatch.setattr(learning_speed, "measure", lambda env_ids, steps, rounds: {
        e: {"env": 900.0, **{n: 30.0 * (i + 1) for i, n in enumerate(names)}} for e in env_ids})
    results = learning_speed.run(["--steps", "10", "--rounds", "1"])
    assert results["command"] == "python -m benchmarks run learning-speed --steps 10 --rounds 1"
    assert list(results["utd"]) == names and list(results["rates"]) == [OURS]
    rows = [r for r in learning_speed.markdown(results).splitlines() if r.startswith("| ")][1:]
    assert [r.split(" | ")[0][2:] for r in rows] == ["env alone, random actions", *names]
    assert "`python -m benchmarks run learning-speed --steps 10 --rounds 1`" in learning_speed.markdown(results)
