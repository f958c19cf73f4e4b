"""A model from a file is rebuilt from numbers, names and weights (sbagents.safe_load), never decoded from pickles.

Every algorithm of ``ALGOS``: a tiny model saved by sbagents, then loaded without its env (spaces from the plain
record) and with it, acts exactly as SB3's own loader's copy. The audit's crafted entries (a numpy dtype whose
pointer numpy would dereference, a module that runs code on import, a class swap, a huge allocation) are never read.
"""

from __future__ import annotations

import base64
import json
import pickle
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from sbagents.algos import ALGOS
from sbagents.atomic import save_model
from sbagents.errors import UsageError
from sbagents.safe_load import load_model, read_model_data
from sbagents.spaces_record import RECORD_KEY, space_from_json, space_to_json


def _small() -> dict[str, Any]:
    return {"policy_kwargs": {"net_arch": [8]}}  # a new dict each time: off-policy algorithms write into it


def _off() -> dict[str, Any]:
    return {"learning_starts": 10, "buffer_size": 100, **_small()}


def _env(algo: str) -> gym.Env:
    spec = ALGOS[algo]
    if spec.masked:
        from sb3_contrib.common.wrappers import ActionMasker

        return ActionMasker(gym.make("CartPole-v1"), lambda env: np.ones(2, dtype=bool))
    if algo in ("qlearning", "sarsa"):
        return gym.make("FrozenLake-v1")
    if spec.supports(gym.make("CartPole-v1").observation_space, gym.make("CartPole-v1").action_space):
        return gym.make("CartPole-v1")
    return gym.make("Pendulum-v1")


def _model(algo: str, env: gym.Env) -> Any:
    cls = ALGOS[algo].cls
    if algo in ("qlearning", "sarsa"):
        return cls("MlpPolicy" if "MlpPolicy" in getattr(cls, "policy_aliases", {}) else next(iter(cls.policy_aliases)),
                   env, seed=0)
    kwargs = _off() if ALGOS[algo].off_policy else _small()
    if algo == "ars":
        kwargs = {"policy_kwargs": {"net_arch": [8]}, "n_delta": 2}
    policy = "MlpLstmPolicy" if ALGOS[algo].recurrent else "MlpPolicy"
    return cls(policy, env, seed=0, **kwargs)


def _observations(env: gym.Env, n: int = 16) -> np.ndarray:
    env.observation_space.seed(0)
    return np.stack([env.observation_space.sample() for _ in range(n)])


@pytest.mark.parametrize("algo", [a for a in ALGOS if a not in ("qlearning", "sarsa")])
def test_every_algorithm_is_rebuilt_exactly(algo: str, tmp_path: Path) -> None:
    env = _env(algo)
    model = _model(algo, env)
    model.learn(40)
    path = save_model(model, tmp_path / "model.zip")
    cls = ALGOS[algo].cls
    reference = cls.load(str(path), device="cpu")  # SB3's loader (the file is ours, so unpickling it is fine here)
    obs = _observations(env)
    expected = reference.predict(obs, deterministic=True)[0]
    for attached in (None, env):
        rebuilt = load_model(cls, path, env=attached)
        np.testing.assert_array_equal(rebuilt.predict(obs, deterministic=True)[0], expected)
        assert rebuilt.observation_space == reference.observation_space
        assert rebuilt.action_space == reference.action_space
        assert rebuilt.num_timesteps == reference.num_timesteps
        assert type(rebuilt.policy) is type(reference.policy)
        for key in ("gamma", "learning_rate", "batch_size", "n_steps", "tau"):
            if isinstance(getattr(reference, key, None), int | float) and key not in ("n_steps", "batch_size"):
                assert getattr(rebuilt, key) == getattr(reference, key), key


def test_the_record_round_trips_every_kind_of_space() -> None:
    spaces = [
        gym.spaces.Box(-1.0, 1.0, (3,), np.float32),
        gym.spaces.Box(np.array([0.0, -np.inf]), np.array([1.0, np.inf]), dtype=np.float64),
        gym.spaces.Box(0, 255, (84, 84, 4), np.uint8),
        gym.spaces.Discrete(5, start=-2),
        gym.spaces.MultiDiscrete([3, 4]),
        gym.spaces.MultiBinary(6),
        gym.spaces.Dict({"observation": gym.spaces.Box(-1, 1, (2,)), "desired_goal": gym.spaces.Discrete(3)}),
        gym.spaces.Tuple((gym.spaces.Discrete(2), gym.spaces.Box(0, 1, (1,)))),
    ]
    for space in spaces:
        record = json.loads(json.dumps(space_to_json(space), allow_nan=False))
        assert space_from_json(record) == space


@pytest.mark.parametrize("record", [
    {"type": "Box", "shape": [10**9], "dtype": "float32", "low": 0, "high": 1},  # a huge allocation
    {"type": "Box", "shape": [2], "dtype": "object", "low": 0, "high": 1},  # object dtype
    {"type": "Discrete", "n": "5"},
    {"type": "Dict", "spaces": [["a", {"type": "Dict", "spaces": []}]] * 2000},
    {"type": "Evil"},
])
def test_a_bad_record_is_refused(record: dict[str, Any], tmp_path: Path) -> None:
    env = gym.make("CartPole-v1")
    model = ALGOS["ppo"].cls("MlpPolicy", env, **_small())
    path = save_model(model, tmp_path / "m.zip")
    _edit(path, lambda data: data.__setitem__(RECORD_KEY, {"observation_space": record,
                                                          "action_space": space_to_json(env.action_space)}))
    with pytest.raises(UsageError) as info:
        load_model(ALGOS["ppo"].cls, path)
    assert "\n" not in str(info.value)


def _edit(path: Path, change: Any) -> None:
    with zipfile.ZipFile(path) as archive:
        files = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(files["data"])
    change(data)
    files["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in files.items():
            archive.writestr(name, content)


def test_a_model_of_another_algorithm_is_named(tmp_path: Path) -> None:
    model = ALGOS["dqn"].cls("MlpPolicy", "CartPole-v1", **_off())
    path = save_model(model, tmp_path / "dqn.zip")
    with pytest.raises(UsageError, match="is a dqn model .* use --algo dqn"):
        load_model(ALGOS["ppo"].cls, path)


def test_env_spaces_that_differ_from_the_record_are_one_line(tmp_path: Path) -> None:
    model = ALGOS["ppo"].cls("MlpPolicy", "CartPole-v1", **_small())
    path = save_model(model, tmp_path / "m.zip")
    with pytest.raises(UsageError, match="observation space"):
        load_model(ALGOS["ppo"].cls, path, env=gym.make("Acrobot-v1"))


def test_weights_that_do_not_fit_are_one_line(tmp_path: Path) -> None:
    path = save_model(ALGOS["ppo"].cls("MlpPolicy", "CartPole-v1", **_small()), tmp_path / "m.zip")
    _edit(path, lambda data: data["policy_kwargs"].__setitem__("net_arch", [16]))
    with pytest.raises(UsageError, match="weights do not fit"):
        load_model(ALGOS["ppo"].cls, path)


# --- the audit's repros: entries that crashed, imported or swapped classes are never read ------------------------
def _pickle_program(body: str) -> bytes:
    """A pickle (protocol 2) built by hand from ``body``'s opcodes."""
    return b"\x80\x02" + body.encode("latin-1") + b"."


def _dtype_o8_scalar() -> bytes:
    """Repro 1: ``numpy.dtype('O8')`` with a state whose flags are 0, then ``scalar(that dtype, b"A" * 8)``: numpy
    dereferences a pointer from the file (SIGSEGV when decoded)."""
    return (b"\x80\x02cnumpy._core.multiarray\nscalar\nq\x00cnumpy\ndtype\nq\x01X\x02\x00\x00\x00O8q\x02K\x00K\x01"
            b"\x87q\x03Rq\x04(K\x03X\x01\x00\x00\x00|q\x05NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tq\x06bh\x04"
            b"C\x08AAAAAAAAq\x07\x86q\x08Rq\x09.")


def _f2py_main() -> bytes:
    """Repro 2: a name whose import runs f2py's command line."""
    return b"\x80\x02cnumpy.f2py.__main__\nmain\nq\x00."


def _class_swap() -> bytes:
    """Repro 3: BUILD with ``{"__class__": torch.nn.Linear}`` in a slot state on a schedule."""
    return (b"\x80\x02cstable_baselines3.common.utils\nConstantSchedule\nq\x00)\x81q\x01N}q\x02X\t\x00\x00\x00"
            b"__class__q\x03ctorch.nn\nLinear\nq\x04s\x86q\x05b.")


def _huge_array() -> bytes:
    """Repro 4: ``numpy.ndarray((125_000_000,), "O")`` (1 GB)."""
    return pickle.dumps(np.ndarray, protocol=2)[:-1] + b"J\x40\x59\x73\x07\x85X\x01\x00\x00\x00O\x86R."


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train

    logs = tmp_path_factory.mktemp("rebuild") / "logs"
    train(TrainSpec("ppo", "sbagents/GridWorld-v0", n_timesteps=64, hyperparams={"n_steps": 32, "batch_size": 32}),
          output=OutputOptions(logs), evaluation=EvalOptions(eval_freq=-1, final_eval_episodes=0),
          execution=ExecOptions(seed=0, verbose=0))
    return logs


_PROGRAM = (
    "import resource, sys\n"
    "from sbagents.evaluate import main\n"
    "code = main(['--algo', 'ppo', '--env', 'sbagents/GridWorld-v0', '-f', sys.argv[1], '-n', '1', '--json'])\n"
    "print('f2py' if 'numpy.f2py' in sys.modules else 'clean')\n"
    "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
    "sys.exit(code)\n"
)


def _evaluate_in_child(logs: Path) -> tuple[dict[str, Any], str, int]:
    """``evaluate --json`` in a child process: its report, whether numpy.f2py got imported, its peak RSS (KiB)."""
    done = subprocess.run([sys.executable, "-c", _PROGRAM, str(logs)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.strip().splitlines()
    return json.loads(lines[-3]), lines[-2], int(lines[-1])


@pytest.fixture(scope="module")
def baseline_rss(run: Path) -> int:
    """The peak RSS of evaluating the untouched run (torch and the envs alone take several hundred MB)."""
    return _evaluate_in_child(run)[2]


@pytest.mark.parametrize("payload", [_dtype_o8_scalar, _f2py_main, _class_swap, _huge_array])
def test_crafted_entries_are_never_decoded(payload: Any, run: Path, baseline_rss: int, tmp_path: Path) -> None:
    """In a child process (a crash would be a signal): ``evaluate`` on a run whose every serialized entry is the
    crafted pickle exits 0, never imports ``numpy.f2py``, and needs no more memory than the untouched run (+50 MB)."""
    import shutil

    logs = Path(shutil.copytree(run, tmp_path / "logs"))
    model = next(logs.glob("ppo/*/sbagents_GridWorld-v0.zip"))
    data = read_model_data(model)
    blob = base64.b64encode(payload()).decode()
    _edit(model, lambda d: d.update({k: {":type:": "<class 'object'>", ":serialized:": blob}
                                     for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v}))
    report, imported, rss = _evaluate_in_child(logs)
    assert report["n_episodes"] == 1
    assert imported == "clean"
    assert rss < baseline_rss + 50 * 1024, (rss, baseline_rss)
