"""Inputs that ended in a traceback, and newcomer paths that gave a misleading answer: each is now one line on
stderr, exit 2, and leaves no run dir. Env names that are not module paths, ``normalize`` on Discrete observations,
YAML files nested or aliased beyond any settings file, a missing optional package (the extra to install is named),
a Ray without RLlib's dependencies; a smoke benchmark run never writes the published results; ``private`` installs
Opacus alone."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import tomllib
import yaml
from cli_helpers import REPO, check_error, last_json, run_main

from benchmarks import __main__ as harness_cli
from benchmarks.harness import Benchmark, registry
from benchmarks.report import MARKDOWN
from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train

QUIET = ("-n", "64", "--verbose", "0", "--eval-freq", "0", "--final-eval-episodes", "0")


# --- env names ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("env", "expected"), [
    (".x", "unknown env id '.x'"),
    ("../../../../etc/passwd", "unknown env id '../../../../etc/passwd'"),
    (":", "is not an env id, a module path or module:name"),
    ("os:", "is not an env id, a module path or module:name"),
    (":CartPole-v1", "is not an env id, a module path or module:name"),
    ("my-pkg.envs:Env-v0", "is not an env id, a module path or module:name"),
])
def test_env_names_that_are_no_module_paths(env: str, expected: str, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    code = run_main("train", "--env", env, "-f", str(tmp_path / "logs"), *QUIET)
    check_error(code, capsys.readouterr().err, expected)
    assert not (tmp_path / "logs").exists()


def test_gym_packages_that_are_no_module_names(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = run_main("train", "--gym-packages", "../x", "-f", str(tmp_path / "logs"), *QUIET)
    check_error(code, capsys.readouterr().err, "--gym-packages: '../x' is not a module name")


# --- normalize on observations VecNormalize cannot normalize -------------------------------------------------------
def test_normalize_on_discrete_observations(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    code = run_main("train", "--algo", "dqn", "--env", "sbagents/GridWorld-v0", "-f", str(logs), *QUIET,
                    "-params", "normalize:True")
    check_error(code, capsys.readouterr().err, "normalize needs Box (or Dict) observations to normalize; "
                                               "sbagents/GridWorld-v0's are Discrete(25)")
    assert not logs.exists()
    # rewards only: SB3's replay buffer cannot store scalar observations under VecNormalize, so off-policy
    # algorithms are refused up front (they used to fail with an IndexError at the first episode end) ...
    code = run_main("train", "--algo", "dqn", "--env", "sbagents/GridWorld-v0", "-f", str(logs), *QUIET,
                    "-params", "normalize:{norm_obs: false}", "learning_starts:16")
    check_error(code, capsys.readouterr().err, "normalize on Discrete(25) observations works with on-policy "
                                               "algorithms only")
    assert not logs.exists()
    # ... and on-policy ones train, past several episode ends
    assert run_main("train", "--algo", "ppo", "--env", "sbagents/GridWorld-v0", "-f", str(logs), *QUIET,
                    "-n", "512", "-params", "normalize:{norm_obs: false}", "n_steps:128", "n_envs:1") == 0
    assert (logs / "ppo" / "sbagents_GridWorld-v0_1" / "vecnormalize.npz").exists()


def test_normalize_arguments_vecnormalize_rejects(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = run_main("train", "--algo", "ppo", "--env", "CartPole-v1", "-f", str(tmp_path / "logs"), *QUIET,
                    "-params", "normalize:{no_such: 1}")
    check_error(code, capsys.readouterr().err, "normalize {'no_such': 1} does not fit CartPole-v1")


# --- YAML files: nesting, aliases, integers ------------------------------------------------------------------------
HOSTILE_YAML = {
    "flow": ("CartPole-v1:\n  env_kwargs: " + "[" * 5000 + "]" * 5000 + "\n", "nested deeper than 64 levels"),
    "block": ("CartPole-v1:\n" + "".join("  " * (i + 1) + f"k{i}:\n" for i in range(1500)),
              "nested deeper than 64 levels"),
    "laughs": ("a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [{', '.join([f'*{p}'] * 10)}]\n" for p, c in zip("abcdefgh", "bcdefghi", strict=True)),
        "more than 200,000 values once its aliases"),
    "recursive": ("CartPole-v1: &r\n  env_kwargs: {x: *r}\n", "is nested deeper than 64 levels"),
    "bigint": ("CartPole-v1:\n  n_envs: " + "9" * 5000 + "\n", "integer out of range"),
    "bad-tag": ("CartPole-v1:\n  n_envs: !!timestamp 2024-99-99\n", "malformed YAML"),
}


@pytest.mark.parametrize("name", list(HOSTILE_YAML))
def test_hostile_conf_files(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text, expected = HOSTILE_YAML[name]
    conf = tmp_path / "conf.yml"
    conf.write_text(text)
    code = run_main("train", "--algo", "ppo", "--env", "CartPole-v1", "-conf", str(conf),
                    "-f", str(tmp_path / "logs"), *QUIET)
    check_error(code, capsys.readouterr().err, expected)
    assert not (tmp_path / "logs").exists()


def test_anchors_of_rl_zoo_files_still_load(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text("base: &base\n  n_steps: 64\n  batch_size: 64\nCartPole-v1:\n  <<: *base\n  n_envs: 1\n")
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", "ppo", "--env", "CartPole-v1", "-conf", str(conf), "-f", str(logs),
                    *QUIET) == 0
    saved = yaml.safe_load((logs / "ppo" / "CartPole-v1_1" / "CartPole-v1" / "config.yml").read_text())
    assert saved["n_steps"] == 64 and saved["n_envs"] == 1


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished PPO CartPole run: the log folder."""
    logs = tmp_path_factory.mktemp("oneline") / "logs"
    train(TrainSpec("ppo", "CartPole-v1", 64, {"n_envs": 1, "n_steps": 64, "batch_size": 64}),
          OutputOptions(logs), EvalOptions(eval_freq=0, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    return logs


@pytest.mark.parametrize("file", ["config.yml", "args.yml"])
@pytest.mark.parametrize("name", ["flow", "block", "recursive", "bigint"])
def test_hostile_run_settings(file: str, name: str, finished: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = finished / "ppo" / "CartPole-v1_1" / "CartPole-v1"
    saved = (folder / file).read_bytes()
    try:
        (folder / file).write_text(HOSTILE_YAML[name][0])
        code = run_main("evaluate", "--algo", "ppo", "--env", "CartPole-v1", "-f", str(finished), "-n", "1")
        check_error(code, capsys.readouterr().err, HOSTILE_YAML[name][1])
    finally:
        (folder / file).write_bytes(saved)
    assert run_main("evaluate", "--algo", "ppo", "--env", "CartPole-v1", "-f", str(finished), "-n", "1",
                    "--json") == 0
    assert last_json(capsys.readouterr().out)["n_episodes"] == 1


# --- missing optional packages -------------------------------------------------------------------------------------
def test_a_missing_optional_env_package_names_its_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    for name in [m for m in sys.modules if m == "mpe2" or m.startswith("mpe2.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "mpe2", None)  # as where the pettingzoo-envs extra is not installed
    expected = "needs the optional package 'mpe2', which is not installed: pip install 'sbagents[pettingzoo-envs]'"
    code = run_main("train", "--env", "mpe2.simple_spread_v3", "-f", str(tmp_path / "logs"), *QUIET)
    check_error(code, capsys.readouterr().err, expected)
    code = run_main("train", "--gym-packages", "mpe2", "-f", str(tmp_path / "logs"), *QUIET)
    check_error(code, capsys.readouterr().err, expected)
    assert not (tmp_path / "logs").exists()


def test_a_ray_without_rllib_dependencies_names_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """Ray is there (its spec is found) but importing RLlib fails, as with a Ray lacking ``dm-tree``."""
    import sbagents.rllib

    monkeypatch.setattr(sbagents.rllib, "ray_available", lambda: True)
    monkeypatch.delitem(sys.modules, "sbagents.rllib.training", raising=False)
    monkeypatch.setitem(sys.modules, "ray", None)
    code = run_main("train", "--backend", "rllib", "--algo", "ppo", "--env", "treasure_hunt_v0",
                    "-f", str(tmp_path / "logs"), "-n", "64")
    check_error(code, capsys.readouterr().err, "pip install 'sbagents[distributed]'")
    assert not (tmp_path / "logs").exists()


# --- benchmarks: a smoke run never writes the published results ----------------------------------------------------
@pytest.fixture()
def fake_bench(monkeypatch: pytest.MonkeyPatch) -> Benchmark:
    fake = Benchmark(name="fake-smoke", kind="speed", results="fake_smoke_never_written.json", summary="a test double",
                     run=lambda argv: {"argv": list(argv)}, render=lambda r: f"## Fake\n\n{r['argv']}")
    monkeypatch.setattr(harness_cli, "registry", lambda: {"fake-smoke": fake})
    return fake


@pytest.mark.parametrize("flag", ["--quick", "--smoke", "--tiny", "--qui"])
def test_a_smoke_run_writes_a_scratch_file_only(flag: str, fake_bench: Benchmark,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    published = MARKDOWN.read_bytes()
    assert harness_cli.main(["run", "fake-smoke", flag]) == 0
    out = capsys.readouterr().out
    assert "smoke run: the published results and BENCHMARKS.md are left alone" in out
    scratch = Path(out.split("results -> ")[1].split(" (smoke run")[0])
    assert scratch.exists() and scratch.parent != fake_bench.results_path.parent
    assert not fake_bench.results_path.exists()
    assert MARKDOWN.read_bytes() == published
    scratch.unlink()
    scratch.parent.rmdir()


def test_a_smoke_run_refuses_the_published_files(fake_bench: Benchmark, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    code = harness_cli.main(["run", "--results", str(fake_bench.results_path), "fake-smoke", "--quick"])
    check_error(code, capsys.readouterr().err, "a smoke run (--quick / --smoke / --tiny) never writes the published")
    code = harness_cli.main(["run", "--output", str(MARKDOWN), "fake-smoke", "--quick"])
    check_error(code, capsys.readouterr().err, "never writes the published BENCHMARKS.md")
    assert not fake_bench.results_path.exists()
    md, results = tmp_path / "B.md", tmp_path / "r.json"  # files of its own: written as asked
    assert harness_cli.main(["run", "--output", str(md), "--results", str(results), "fake-smoke", "--quick"]) == 0
    assert results.exists() and "## Fake" in md.read_text()


def test_every_smoke_mode_of_the_registry_is_recognised() -> None:
    benchmarks = registry()
    assert benchmarks["export-latency"].is_smoke(["--quick"])
    assert not benchmarks["export-latency"].is_smoke(["--train-steps", "10"])
    assert benchmarks["callback-overhead"].is_smoke(["--quick"])


# --- extras --------------------------------------------------------------------------------------------------------
def test_the_private_extra_is_opacus_alone() -> None:
    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert [req.split(">")[0] for req in extras["private"]] == ["opacus"]
    assert any(req.startswith("flwr[simulation]") for req in extras["federated"])
    assert "federated" in (REPO / ".ci" / "run").read_text()
