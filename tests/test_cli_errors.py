"""Every CLI fed malformed values: one clear line on stderr, exit code 2, no traceback, nothing left behind.

The matrix runs each CLI's ``main`` in this process through :func:`sbagents.cli_common.run` (the same error handling as
``python -m``, without an interpreter start per case); one case per CLI also goes through a real subprocess.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from cli_helpers import check_error, cli_subprocess, run_main

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, RunRef, TrainSpec, export, train

GRID = "sbagents/GridWorld-v0"


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A log folder with a tabular and a neural GridWorld run, the neural one exported."""
    folder = tmp_path_factory.mktemp("logs")
    quiet = (OutputOptions(folder), EvalOptions(final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    train(TrainSpec("qlearning", GRID), *quiet)
    train(TrainSpec("ppo", GRID, 256, {"n_envs": 2, "n_steps": 64, "batch_size": 64, "n_epochs": 1}), *quiet)
    export(RunRef("ppo", GRID, folder), n_observations=10)
    return folder


TRAIN_CASES = [
    (["--algo", "ppo", "--robust", "sa:0.2"], "--robust sa trains ddpg, td3, not ppo"),
    (["--algo", "ppo", "--constraint", "pid"], "--constraint needs --cost-limit X"),
    (["--algo", "a2c", "--constraint", "lagrangian", "--cost-limit", "1"], "--constraint trains ppo"),
    (["--algo", "ppo", "--constraint", "lagrangian", "--cost-limit", "-1"], "--cost-limit must be >= 0"),
    (["--algo", "ppo", "--constraint", "foo"], "argument --constraint: invalid choice"),
    (["--algo", "td3", "--env", "Pendulum-v1", "--robust", "fgsm:0.1"],
     "--robust 'fgsm:0.1': expected METHOD:EPS[,KEY=VALUE...] with METHOD sa, adv or sa+adv"),
    (["--algo", "td3", "--env", "Pendulum-v1", "--robust", "sa:0"], "EPS must be a finite number > 0"),
    (["--env", "GridWrld-v0"], "unknown env id 'GridWrld-v0'; did you mean sbagents/GridWorld-v0"),
    (["--algo", "foo"], "unknown algo 'foo'; available: a2c, ppo"),
    (["--algo", "sac"],
     "sac cannot learn sbagents/GridWorld-v0 (observation Discrete, action Discrete); algos that can: a2c"),
    (["--algo", "qlearning", "--env", "Pendulum-v1"], "qlearning cannot learn Pendulum-v1"),
    (["-n", "0"], "-n/--n-timesteps must be a positive integer, got 0"),
    (["-n", "-5"], "-n/--n-timesteps must be a positive integer, got -5"),
    (["-params", "learning_rate"], "-params expects key:value pairs"),
    (["-params", "learning_rate:[1,"], "is not a YAML scalar, list or mapping"),
    (["-params", "learnin_rate:0.1"], "unknown hyperparameter(s) learnin_rate for dqn"),
    (["-params", "learning_rate:__import__('os').system('true')"], "learning_rate must be a number"),
    (["--env-kwargs", "sise:5"], "unknown env kwarg(s) sise for sbagents/GridWorld-v0; accepted: goal"),
    (["-params", "eval_env_kwargs:{sise: 5}"], "unknown env kwarg(s) sise for sbagents/GridWorld-v0; accepted: goal"),
    (["-params", "eval_env_kwargs:5"], "eval_env_kwargs must be a mapping, got 5"),
    (["--env-kwargs", "size:abc"], "cannot create sbagents/GridWorld-v0 with env kwargs size='abc': size must be"),
    (["--env-kwargs", "obstacles:5"], "obstacles must be a list of (row, col) cells, got 5"),
    (["--env-kwargs", "max_steps:0"], "max_steps must be an integer in 1..1,000,000,000, got 0"),
    (["--env", "SmartHome-v0", "--algo", "ppo", "--env-kwargs", "preferred_temp:abc"],
     "cannot create sbagents/SmartHome-v0 with env kwargs preferred_temp='abc'"),
    (["--env", "treasure_hunt_v0", "--algo", "ppo", "--env-kwargs", "n_agents:-1"],
     "cannot create treasure_hunt_v0 with env kwargs"),
    (["-i", "missing.zip"], "--trained-agent missing.zip does not exist"),
    (["--num-threads", "x"], "argument --num-threads: invalid int value"),
    (["--seed", "abc"], "argument --seed: invalid int value"),
    (["--eval-episodes", "0"], "--eval-episodes must be >= 1, got 0"),
    (["--n-eval-envs", "0"], "--n-eval-envs must be >= 1, got 0"),
    (["--final-eval-episodes", "-1"], "--final-eval-episodes must be >= 0, got -1"),
    (["--log-interval", "0"], "--log-interval must be >= 1 or -1 (automatic), got 0"),
    (["--device", "foo"], "--device 'foo' is not a torch device"),
    (["--vec-env", "foo"], "argument --vec-env: invalid choice: 'foo'"),
    (["--gym-packages", "no_such_package_xyz"], "--gym-packages: cannot import 'no_such_package_xyz'"),
    (["--algo", "qlearning", "--adversarial-eval", "gaussian:0.1"],
     "--adversarial-eval gaussian_0.1: observation attacks need a neural-network policy"),
    (["--adversarial-eval", "foo:0.1"], "--adversarial-eval: invalid attack spec 'foo:0.1'"),
    (["--fairness", "x", "--bins", "0"], "--bins must be >= 1, got 0"),
]


@pytest.mark.parametrize(("args", "expected"), TRAIN_CASES, ids=[" ".join(a) for a, _ in TRAIN_CASES])
def test_bad_train_input(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], expected: str,
                         monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    code = run_main("train", "--algo", "dqn", "-f", str(tmp_path / "logs"), *args)
    check_error(code, capsys.readouterr().err, expected)
    assert not (tmp_path / "logs").exists(), "a run dir (or the folders made for it) was left behind"


def test_config_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad_yaml = tmp_path / "bad.yml"
    bad_yaml.write_text("default:\n  n_timesteps: 10\n  policy: [oops\n")
    no_entry = tmp_path / "no_entry.yml"
    no_entry.write_text("CartPole-v1:\n  n_timesteps: 10\n")
    cases = [
        (bad_yaml, f"malformed YAML in {bad_yaml} line 4"),
        (no_entry, "has no entry for 'sbagents/GridWorld-v0' and no 'default' (entries: CartPole-v1)"),
        (tmp_path / "nope.yml", "does not exist"),
    ]
    for conf, expected in cases:
        code = run_main("train", "--algo", "dqn", "-conf", str(conf), "-f", str(tmp_path))
        check_error(code, capsys.readouterr().err, expected)
    assert not (tmp_path / "dqn").exists()


def test_not_a_model_and_unwritable_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    not_model = tmp_path / "model.zip"
    not_model.write_text("not a zip")
    check_error(run_main("train", "-i", str(not_model), "-f", str(tmp_path / "logs")), capsys.readouterr().err,
                "is not an SB3 model file")
    blocker = tmp_path / "file"
    blocker.write_text("")
    check_error(run_main("train", "-f", str(blocker / "logs")), capsys.readouterr().err,
                f"log folder {blocker / 'logs'} is not writable")


def _other_cli_cases(logs: Path, tmp: Path) -> list[tuple[str, list[str], str]]:
    run_args = ["--env", "GridWorld-v0", "-f", str(logs)]
    ppo, qlearning = ["--algo", "ppo", *run_args], ["--algo", "qlearning", *run_args]
    policy = str(logs / "ppo" / "sbagents_GridWorld-v0_1" / "export" / "policy.onnx")
    garbage = tmp / "garbage.onnx"
    garbage.write_text("not onnx")
    blocked = tmp / "file"
    blocked.write_text("")
    return [
        ("evaluate", [*ppo, "-n", "0"], "the number of evaluation episodes must be >= 1, got 0"),
        ("evaluate", [*ppo, "--exp-id", "-1"], "--exp-id must be >= 0 (0: the latest run), got -1"),
        ("evaluate", [*ppo, "--exp-id", "9"], "no run sbagents_GridWorld-v0_9"),
        ("evaluate", ["--algo", "dqn", *run_args], "no dqn run for sbagents/GridWorld-v0"),
        ("evaluate", ["--algo", "dqn", "--env", "Nope-v0", "-f", str(logs)], "unknown env id"),
        ("evaluate", [*ppo, "--attack", "foo:0.1"], "--attack: invalid attack spec 'foo:0.1'"),
        ("evaluate", [*ppo, "--attack", "pgd:-1"], "eps must be a finite number >= 0"),
        ("evaluate", [*qlearning, "--attack", "fgsm:0.1"], "--attack fgsm_0.1: observation attacks need a neural"),
        ("evaluate", [*ppo, "--fairness", "cell", "--bins", "0"], "--bins must be >= 1, got 0"),
        ("evaluate", [*ppo, "--fairness", "nokey"], "episode info has no attribute 'nokey'"),
        ("evaluate", [*ppo, "-n", "x"], "argument -n/--n-episodes: invalid int value"),
        ("export", qlearning, "cannot export qlearning: export writes neural-network policies to ONNX"),
        ("export", [*ppo, "--n-observations", "0"], "--n-observations must be >= 1, got 0"),
        ("export", [*ppo, "--out", str(blocked / "x")], f"cannot use {blocked}"),
        ("serve", ["--model", str(tmp / "nope.onnx")], "model file not found"),
        ("serve", ["--model", str(garbage)], f"invalid ONNX model {garbage}"),
        ("serve", ["--model", policy, "--meta", str(tmp / "nope.json")], "sidecar not found"),
        ("serve", ["--model", policy, "--csv", str(blocked / "d.csv")], f"cannot use {blocked}"),
        ("serve", [], "the following arguments are required: --model"),
        ("record_video", [*ppo, "-n", "0"], "-n/--n-steps must be >= 1, got 0"),
        ("record_video", [*ppo, "--fps", "0"], "--fps must be > 0, got 0.0"),
        ("record_video", [*ppo, "-n", "5", "-o", str(blocked / "v")], f"cannot use {blocked}"),
        ("record_video", ["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp / "none")], "no ppo run"),
        ("play", ppo, "sbagents/GridWorld-v0 is not a turn-based game"),
        ("play", ["--algo", "ppo_mask", "--env", "pettingzoo.classic.tictactoe_v3", "-f", str(logs)],
         "no ppo_mask run for tictactoe_v3"),
        ("evaluate", [*ppo, "--opponent", "random"], "--opponent applies to turn-based games"),
        ("plot", ["-f", str(tmp / "none")], "does not exist"),
        ("plot", ["-f", str(logs), "--window", "-1"], "--window must be >= 0 (0: automatic), got -1"),
        ("plot", ["-f", str(logs), "-o", str(blocked / "c.png")], f"cannot use {blocked}"),
        ("plot", ["-f", str(logs), "--algo", "nope"], "no runs for nope"),
        ("plot", ["-f", str(logs), "--x", "steps"], "argument --x: invalid choice"),
        ("tune", ["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp), "-n", "0"],
         "-n/--n-timesteps must be a positive integer, got 0"),
        ("tune", ["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp), "--n-jobs", "0"],
         "--n-jobs must be >= 1, got 0"),
        ("tune", ["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp), "--n-evaluations", "0"],
         "--n-evaluations must be >= 1, got 0"),
        ("tune", ["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp), "--eval-episodes", "0"],
         "--eval-episodes must be >= 1, got 0"),
        ("tune", ["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp), "--storage", "foo://bar", "-n", "64"],
         "--storage foo://bar: cannot open the study"),
        ("tune", ["--algo", "sac", "--env", "GridWorld-v0", "-f", str(tmp), "-n", "64"], "sac cannot learn"),
        ("tune", ["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp), "--n-trials", "0"],
         "--n-trials must be >= 1, got 0"),
        ("dashboard.__main__", ["-f", str(tmp / "none")], f"-f/--log-folder {tmp / 'none'}: no such folder"),
        ("dashboard.__main__", ["-f", str(logs), "--host", "0.0.0.0"], "--host 0.0.0.0 is reachable from other"),
        ("dashboard.__main__", ["-f", str(logs), "--host", "0.0.0.0", "--token", "short"],
         "--token must be at least 8 characters"),
        ("dashboard.__main__", ["-f", str(logs), "--port", "70000"], "--port must be 0-65535, got 70000"),
        ("dashboard.__main__", ["-f", str(logs), "--port", "x"], "argument --port: invalid int value"),
    ]


def test_bad_input_to_every_other_cli(logs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = sorted(p.relative_to(logs) for p in logs.rglob("*"))
    cases = _other_cli_cases(logs, tmp_path)
    assert {module for module, _, _ in cases} == {"evaluate", "export", "serve", "record_video", "plot", "tune",
                                                  "play", "dashboard.__main__"}
    for module, args, expected in cases:
        code = run_main(module, *args)
        check_error(code, capsys.readouterr().err, expected)
    assert sorted(p.relative_to(logs) for p in logs.rglob("*")) == before, "a failed command wrote into the runs"
    assert not list(tmp_path.rglob("*.db")), "a refused tune left a study behind"


@pytest.mark.slow  # eight new interpreters (each CLI's ``__main__`` block is what this checks)
def test_real_entry_points_print_one_line(logs: Path, tmp_path: Path) -> None:
    """One malformed call per CLI through ``python -m``: the interpreter path is traceback-free as well."""
    calls = {
        "train": (["--algo", "ppo", "--env-kwargs", "size:abc", "-f", str(tmp_path)], "size must be"),
        "evaluate": (["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(logs), "-n", "0"], "must be >= 1"),
        "export": (["--algo", "qlearning", "--env", "GridWorld-v0", "-f", str(logs)], "cannot export qlearning"),
        "serve": (["--model", str(tmp_path / "nope.onnx")], "model file not found"),
        "record_video": (["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(logs), "--fps", "0"], "--fps"),
        "plot": (["-f", str(logs), "--window", "-1"], "--window"),
        "tune": (["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp_path), "-n", "0"], "-n/--n-timesteps"),
        "play": (["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(logs)], "not a turn-based game"),
    }
    # subprocesses (what a real ``python -m`` prints is the point), two at a time: they wait mostly on imports
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = pool.map(lambda call: cli_subprocess(call[0], *call[1][0], cwd=tmp_path), calls.items())
        for result, (_, expected) in zip(results, calls.values(), strict=True):
            check_error(result.returncode, result.stderr, expected)
    assert not list(tmp_path.glob("*/*")), "a refused command left files behind"
