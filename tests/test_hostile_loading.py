"""Hostile and broken run dirs, models, configs and flags (docs/security.md).

Every malicious file here holds a pickle that would create a marker file if unpickled: loading must refuse it in
one line (exit 2, no traceback, the marker never appears). ``--trust-run`` loads an older run's pickles as they are.
Broken files (truncated, empty, binary, of the wrong shape) give one line too.
"""

from __future__ import annotations

import base64
import json
import os
import pickle
import shlex
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from cli_helpers import run_main
from hypothesis import given, seed, settings
from hypothesis import strategies as st
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, ReplayBufferOptions, TrainSpec, train
from sbagents.errors import UsageError
from sbagents.safe_load import TRUST_FLAG, UntrustedContentError, load_model, read_model_data

ENV = "sbagents/SmartHome-v0"
STEM = "sbagents_SmartHome-v0"


class _Evil:
    """Unpickling it runs ``touch <marker>``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return os.system, (f"touch {shlex.quote(str(self.marker))}",)


def evil_pickle(marker: Path) -> bytes:
    return pickle.dumps(_Evil(marker))


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished DDPG SmartHome run (VecNormalize statistics, a checkpoint, a replay buffer): the log folder."""
    logs = tmp_path_factory.mktemp("hostile") / "logs"
    train(TrainSpec("ddpg", ENV, n_timesteps=200, hyperparams={"learning_starts": 50}),
          output=OutputOptions(logs, save_freq=200), features=[ReplayBufferOptions(save=True)],
          evaluation=EvalOptions(eval_freq=-1, final_eval_episodes=0), execution=ExecOptions(seed=0, verbose=0))
    return logs


@pytest.fixture()
def logs(trained: Path, tmp_path: Path) -> Path:
    """A copy of the trained log folder to tamper with."""
    return Path(shutil.copytree(trained, tmp_path / "logs"))


def run_dir(logs: Path) -> Path:
    return logs / "ddpg" / f"{STEM}_1"


def one_line_error(capsys: pytest.CaptureFixture[str], code: int, *expected: str) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for text in expected:
        assert text in lines[0], lines[0]
    return lines[0]


def evaluate(logs: Path, *extra: str) -> int:
    return run_main("evaluate", "--algo", "ddpg", "--env", ENV, "-f", str(logs), "-n", "1", *extra)


def replace_entry(model: Path, key: str, payload: bytes) -> None:
    """Put ``payload`` as the serialized value of the ``data`` entry ``key`` of an SB3 zip."""
    with zipfile.ZipFile(model) as archive:
        files = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(files["data"])
    data[key] = {":type:": "<class 'object'>", ":serialized:": base64.b64encode(payload).decode()}
    files["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(model, "w") as archive:
        for name, content in files.items():
            archive.writestr(name, content)


def serialized_keys(model: Path) -> list[str]:
    return [k for k, v in read_model_data(model).items() if isinstance(v, dict) and ":serialized:" in v]


# --- models -----------------------------------------------------------------------------------------------------
def test_a_clean_run_loads_without_trust(logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert evaluate(logs, "--json") == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["n_episodes"] == 1 and np.isfinite(report["mean_return"])


def test_code_in_any_model_entry_never_runs(logs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No ``:serialized:`` entry is decoded: a model whose entries would run code evaluates, exports and continues
    training as it is (rebuilt from the run's settings, plain data and weights), and the code never runs."""
    model = run_dir(logs) / f"{STEM}.zip"
    keys = serialized_keys(model)
    assert {"observation_space", "action_space", "policy_class", "lr_schedule", "action_noise"} <= set(keys)
    marker = tmp_path / "ran"
    for key in keys:
        replace_entry(model, key, evil_pickle(marker))
    assert evaluate(logs) == 0
    assert run_main("export", "--algo", "ddpg", "--env", ENV, "-f", str(logs)) == 0
    code = run_main("train", "--algo", "ddpg", "--env", ENV, "-f", str(tmp_path / "more"), "-n", "50", "--verbose",
                    "0", "-i", str(model))
    assert code == 0, capsys.readouterr().err
    assert not marker.exists()


def test_an_opponent_zip_with_code_is_refused(logs: Path, tmp_path: Path) -> None:
    from sbagents.games.players import load_model

    model = run_dir(logs) / f"{STEM}.zip"
    marker = tmp_path / "ran"
    replace_entry(model, "policy_class", evil_pickle(marker))
    with pytest.raises(UntrustedContentError, match="policy class"):
        load_model(str(model))
    assert not marker.exists()


@pytest.mark.parametrize("damage", ["truncated", "empty", "garbage", "no data", "bad json"])
def test_a_broken_model_file_is_one_line(damage: str, logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = run_dir(logs) / f"{STEM}.zip"
    content = model.read_bytes()
    if damage == "truncated":
        model.write_bytes(content[: len(content) // 2])
    elif damage == "empty":
        model.write_bytes(b"")
    elif damage == "garbage":
        model.write_bytes(os.urandom(2048))
    else:
        with zipfile.ZipFile(model, "w") as archive:
            archive.writestr("data" if damage == "bad json" else "other", "{not json")
    one_line_error(capsys, evaluate(logs), str(model))
    one_line_error(capsys, run_main("export", "--algo", "ddpg", "--env", ENV, "-f", str(logs)), str(model))


def test_a_truncated_checkpoint_is_one_line(logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    checkpoint = run_dir(logs) / "rl_model_200_steps.zip"
    checkpoint.write_bytes(checkpoint.read_bytes()[:100])
    one_line_error(capsys, evaluate(logs, "--load-checkpoint", "200"), "rl_model_200_steps.zip")


# --- VecNormalize statistics and replay buffers -----------------------------------------------------------------
def test_statistics_and_buffers_are_plain_files(logs: Path) -> None:
    folder = run_dir(logs)
    for name in ("vecnormalize.npz", "rl_model_vecnormalize_200_steps.npz", "replay_buffer.npz"):
        with np.load(folder / name, allow_pickle=False) as data:  # no object arrays: nothing to unpickle
            assert data.files
    assert not list(folder.rglob("*.pkl"))


def test_a_legacy_vecnormalize_pickle_needs_trust(logs: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    folder = run_dir(logs)
    (folder / "vecnormalize.npz").unlink()
    marker = tmp_path / "ran"
    (folder / "vecnormalize.pkl").write_bytes(evil_pickle(marker))
    one_line_error(capsys, evaluate(logs), "vecnormalize.pkl", TRUST_FLAG)
    one_line_error(capsys, run_main("export", "--algo", "ddpg", "--env", ENV, "-f", str(logs)), TRUST_FLAG)
    assert not marker.exists()
    stats = VecNormalize(make_vec_env(ENV, n_envs=1))  # an honest pickle from an older run loads when trusted
    stats.save(str(folder / "vecnormalize.pkl"))
    assert evaluate(logs, TRUST_FLAG) == 0


def test_garbage_statistics_are_one_line(logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stats = run_dir(logs) / "vecnormalize.npz"
    stats.write_bytes(os.urandom(300))
    one_line_error(capsys, evaluate(logs), "vecnormalize.npz")
    np.savez(stats, **{"obs_rms//mean": np.zeros(3)})  # a valid npz, but not ours
    one_line_error(capsys, evaluate(logs), "vecnormalize.npz")


def test_a_replay_buffer_pickle_beside_a_model_needs_trust(logs: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    folder = run_dir(logs)
    (folder / "replay_buffer.npz").unlink()
    marker = tmp_path / "ran"
    (folder / "replay_buffer.pkl").write_bytes(evil_pickle(marker))
    code = run_main("train", "--algo", "ddpg", "--env", ENV, "-f", str(tmp_path / "more"), "-n", "50", "--verbose",
                    "0", "-i", str(folder / f"{STEM}.zip"))
    one_line_error(capsys, code, "replay_buffer.pkl", TRUST_FLAG)
    assert not marker.exists()


def test_a_replay_buffer_resumes_exactly(logs: Path) -> None:
    from stable_baselines3 import DDPG

    from sbagents.state_files import load_replay_buffer, save_replay_buffer

    model = DDPG("MlpPolicy", make_vec_env(ENV, n_envs=1), buffer_size=500, learning_starts=10)
    model.learn(60)
    path = save_replay_buffer(model.replay_buffer, logs / "buffer.npz")
    fresh = DDPG("MlpPolicy", make_vec_env(ENV, n_envs=1), buffer_size=500)
    load_replay_buffer(fresh.replay_buffer, path)
    assert fresh.replay_buffer.pos == model.replay_buffer.pos == 60
    np.testing.assert_array_equal(fresh.replay_buffer.observations, model.replay_buffer.observations)
    np.testing.assert_array_equal(fresh.replay_buffer.actions, model.replay_buffer.actions)
    smaller = DDPG("MlpPolicy", make_vec_env(ENV, n_envs=1), buffer_size=100)
    with pytest.raises(UsageError, match="buffer_size 500"):
        load_replay_buffer(smaller.replay_buffer, path)


# --- run files and config import paths --------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "content", "expected"), [
    ("config.yml", b"\x89PNG\r\n\x1a\n\x00\xff\xfe", "config.yml"),
    ("config.yml", b"- a\n- list\n", "YAML mapping"),
    ("args.yml", b"groups: [unclosed\n", "args.yml"),
    ("args.yml", b"- a\n- list\n", "YAML mapping"),
])
def test_broken_run_settings_are_one_line(name: str, content: bytes, expected: str, logs: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    (run_dir(logs) / STEM / name).write_bytes(content)
    one_line_error(capsys, evaluate(logs), expected)
    one_line_error(capsys, run_main("export", "--algo", "ddpg", "--env", ENV, "-f", str(logs)), expected)
    one_line_error(capsys, run_main("plot", "-f", str(logs), "--output", str(logs / "curves.png")), expected)


def test_a_run_config_cannot_import_code(logs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    marker = tmp_path / "ran"
    config = run_dir(logs) / STEM / "config.yml"
    entry = yaml.safe_load(config.read_text())
    entry["env_wrapper"] = [{"pydoc.pipepager": {"text": "x", "cmd": f"touch {marker}"}}]
    config.write_text(yaml.safe_dump(entry))
    one_line_error(capsys, evaluate(logs), "pydoc.pipepager", "allow-list")
    assert not marker.exists()


@pytest.mark.parametrize(("override", "expected"), [
    ("callback:[{subprocess.call: {args: [touch, MARKER]}}]", "allow-list"),
    ("callback:[{os.system: {command: touch MARKER}}]", "allow-list"),
    ("callback:[{stable_baselines3.common.save_util.load_from_pkl: {path: MARKER}}]", "not a BaseCallback class"),
    ("env_wrapper:[sbagents.core.experiment.resolve]", "not a Wrapper"),
    ("policy_kwargs:{activation_fn: builtins.exec}", "allow-list"),
])
def test_overrides_cannot_import_code(override: str, expected: str, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    marker = tmp_path / "ran"
    code = run_main("train", "--algo", "ppo", "--env", "GridWorld-v0", "-f", str(tmp_path / "logs"), "-n", "64",
                    "--verbose", "0", "-params", override.replace("MARKER", str(marker)))
    one_line_error(capsys, code, expected)
    assert not marker.exists() and not (tmp_path / "logs").exists()


# --- bytes where weights belong -----------------------------------------------------------------------------------
@seed(35)
@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_weight_bytes_only_ever_give_a_one_line_error(trained: Path, data: bytes) -> None:
    """``policy.pth`` is read with ``torch.load(weights_only=True)``: garbage is one line, never a crash."""
    from stable_baselines3 import DDPG

    source = run_dir(trained) / f"{STEM}.zip"
    with zipfile.ZipFile(source) as archive:
        files = {name: archive.read(name) for name in archive.namelist()}
    files["policy.pth"] = data
    target = Path(trained).parent / "fuzzed.zip"
    with zipfile.ZipFile(target, "w") as archive:
        for name, content in files.items():
            archive.writestr(name, content)
    with pytest.raises(UsageError) as info:
        load_model(DDPG, target)
    assert "\n" not in str(info.value)


def test_trust_run_loads_what_is_beyond_plain_data(logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A model from another tool whose schedule is a closure: rebuilt by default (the closure is never decoded),
    unpickled as SB3 does with --trust-run; a garbage legacy pickle is one line even when trusted."""
    import cloudpickle

    model = run_dir(logs) / f"{STEM}.zip"
    rate = 1e-3
    replace_entry(model, "lr_schedule", cloudpickle.dumps(lambda progress: rate * progress))
    assert evaluate(logs) == 0
    assert evaluate(logs, TRUST_FLAG) == 0
    capsys.readouterr()
    folder = run_dir(logs)
    (folder / "vecnormalize.npz").unlink()
    (folder / "vecnormalize.pkl").write_bytes(os.urandom(64))
    one_line_error(capsys, evaluate(logs, TRUST_FLAG), "vecnormalize.pkl is corrupt")
