"""The BenchMARL side of ``benchmarl-spread``, run by the Python of BenchMARL's own venv (never imports sbagents).

Three commands (``python benchmarks/learning/benchmarl_venv.py train|eval|collect ...``, with the venv's python):

- ``train``: BenchMARL's MAPPO or IPPO on PettingZoo/mpe2 ``simple_spread_v3`` (N=3, 25 steps, discrete actions,
  local_ratio 0.5) with BenchMARL's default experiment, algorithm and MLP configs except the settings of
  :func:`experiment_overrides`; keeps the policy's weights at each frame budget (the first batch that reaches it) and
  at each wall-time budget (the last batch that ends within it), and writes ``train.json`` (frames, seconds,
  collection seconds of every kept policy and of the whole run);
- ``eval``: each kept policy, greedy, on the benchmark's evaluation episodes (:func:`spread_episodes`: episode ``k``
  reset with seed ``seed + k``), printed as one JSON line;
- ``collect``: the collector's speed alone (``spread-throughput``).

BenchMARL counts frames as env (team) steps: one frame is one step of the 3-agent env, so agent steps = 3 x frames.
Module level needs only numpy and the standard library (the benchmark registry imports every module of this folder,
and the tests run :func:`spread_episodes` with a stand-in policy); torch, torchrl and benchmarl are imported by the
commands.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: The task: mpe2 simple_spread as the benchmark evaluates it (and as BenchMARL is configured to train it).
SPREAD_KWARGS: dict[str, Any] = {"N": 3, "max_cycles": 25, "local_ratio": 0.5, "continuous_actions": False}

#: Agents of the team.
N_AGENTS = 3


def experiment_overrides(save_folder: str, frames_per_batch: int | None = None) -> dict[str, Any]:
    """The values this benchmark changes in BenchMARL's default experiment config, and why.

    - ``prefer_continuous_actions: False``: MPE supports both action kinds and BenchMARL's default prefers continuous;
      the task is the discrete one.
    - ``evaluation``/``render: False``, ``loggers: []``, ``create_json: False``: the benchmark evaluates the kept
      policies itself on its own 1,000 episodes (BenchMARL's periodic evaluation would cost training time; wandb is
      not installed).
    - ``max_n_frames``: large; the run stops itself when every budget is reached (:class:`BudgetCallback`).
    - ``on_policy_collected_frames_per_batch``: BenchMARL's 6,000 unless ``frames_per_batch`` is given (tests).
    """
    out: dict[str, Any] = {"prefer_continuous_actions": False, "evaluation": False, "render": False, "loggers": [],
                           "create_json": False, "save_folder": save_folder, "max_n_frames": 10**9,
                           "checkpoint_at_end": False, "checkpoint_interval": 0, "sampling_device": "cpu",
                           "train_device": "cpu", "buffer_device": "cpu"}
    if frames_per_batch is not None:
        out["on_policy_collected_frames_per_batch"] = frames_per_batch
        out["on_policy_minibatch_size"] = min(400, frames_per_batch)
    return out


def spread_episodes(act: Callable[[np.ndarray], np.ndarray], n_episodes: int, seed: int,
                    batch: int = 100) -> list[float]:
    """Team returns of ``n_episodes`` mpe2 simple_spread episodes (:data:`SPREAD_KWARGS`), episode ``k`` reset with
    seed ``seed + k``; ``batch`` episodes run side by side so that the policy is called once per step for all.

    :param act: observations of ``B`` teams, shape (B, 3, obs_dim), agents in ``possible_agents`` order -> their
        discrete actions, shape (B, 3).
    :return: per episode, the sum over the agents of their 25-step returns.
    """
    from mpe2 import simple_spread_v3

    envs = [simple_spread_v3.parallel_env(**SPREAD_KWARGS) for _ in range(max(1, min(batch, n_episodes)))]
    agents = list(envs[0].possible_agents)
    returns: list[float] = []
    try:
        for first in range(0, n_episodes, len(envs)):
            group = envs[:min(len(envs), n_episodes - first)]
            obs = [env.reset(seed=seed + first + i)[0] for i, env in enumerate(group)]
            totals = np.zeros(len(group))
            while group[0].agents:  # simple_spread episodes all last max_cycles steps
                actions = np.asarray(act(np.stack([[o[a] for a in agents] for o in obs])))
                for i, env in enumerate(group):
                    obs[i], rewards, _, _, _ = env.step({a: int(actions[i, j]) for j, a in enumerate(agents)})
                    totals[i] += float(sum(rewards.values()))
            returns.extend(totals.tolist())
    finally:
        for env in envs:
            env.close()
    return returns


def _install_mpe2() -> None:
    """Make TorchRL's PettingZoo wrapper find ``simple_spread_v3`` in mpe2.

    PettingZoo >= 1.25 moved MPE into the mpe2 package; TorchRL looks tasks up in
    ``pettingzoo.utils.all_modules.all_environments``, which no longer lists them (and fails to import without the
    Atari extras), so the lookup table is replaced by one holding mpe2's module.
    """
    import types

    from mpe2 import simple_spread_v3

    stub = types.ModuleType("pettingzoo.utils.all_modules")
    stub.all_environments = {"mpe/simple_spread_v3": simple_spread_v3}  # type: ignore[attr-defined]
    sys.modules["pettingzoo.utils.all_modules"] = stub


def build_experiment(algo: str, seed: int, save_folder: str, frames_per_batch: int | None = None,
                     callbacks: Sequence[Any] = ()) -> Any:
    """BenchMARL's :class:`Experiment` of ``algo`` (``mappo`` or ``ippo``) on simple_spread (N=3, 25 steps,
    local_ratio 0.5, discrete actions), default configs but :func:`experiment_overrides`."""
    import torch
    from benchmarl.algorithms import IppoConfig, MappoConfig
    from benchmarl.environments import PettingZooTask
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    torch.set_num_threads(1)
    _install_mpe2()
    config = ExperimentConfig.get_from_yaml()
    for key, value in experiment_overrides(save_folder, frames_per_batch).items():
        setattr(config, key, value)
    task = PettingZooTask.SIMPLE_SPREAD.get_from_yaml()
    task.config.update({k: SPREAD_KWARGS[k] for k in ("N", "max_cycles", "local_ratio")})
    algorithms = {"mappo": MappoConfig, "ippo": IppoConfig}
    if algo not in algorithms:
        raise SystemExit(f"unknown algorithm {algo!r}: one of {', '.join(algorithms)}")
    return Experiment(task=task, algorithm_config=algorithms[algo].get_from_yaml(),
                      model_config=MlpConfig.get_from_yaml(), critic_model_config=MlpConfig.get_from_yaml(),
                      seed=seed, config=config, callbacks=list(callbacks))


class StopTraining(Exception):
    """Raised by :class:`BudgetCallback` when every budget has been reached."""


class BudgetCallback:
    """A BenchMARL callback (duck-typed: BenchMARL only calls its hooks) that keeps the policy at each budget and
    stops the run after the last one.

    Policies go to ``out/policy_frames<F>.pt`` (the first batch with at least F frames) and
    ``out/policy_seconds<S>.pt`` (the last batch that ended within S seconds of :meth:`begin`); :meth:`save` returns
    frames, seconds and collection seconds of each. Module level, as BenchMARL pickles its callbacks.

    :param max_seconds: stop here even if a budget is not reached.
    """

    def __init__(self, out: Path, frame_budgets: Sequence[int], second_budgets: Sequence[float],
                 max_seconds: float) -> None:
        self.experiment: Any = None
        self.out, self.frame_budgets, self.second_budgets = out, list(frame_budgets), list(second_budgets)
        self.max_seconds = max_seconds
        self.start = self.last = time.perf_counter()
        self.frames = 0
        self.collection_s = 0.0
        self.kept: dict[str, dict[str, Any]] = {}
        self.pending: dict[str, dict[str, Any]] = {}
        self.total: dict[str, Any] | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "experiment"}

    def begin(self) -> None:
        """Start the clock (just before ``experiment.run()``)."""
        self.start = self.last = time.perf_counter()

    def on_setup(self) -> None:
        """BenchMARL hook (unused)."""

    def on_load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """BenchMARL hook (unused)."""

    def on_train_step(self, batch: Any, group: str) -> None:
        """BenchMARL hook (unused)."""

    def on_evaluation_end(self, rollouts: list[Any]) -> None:
        """BenchMARL hook (unused)."""

    def on_state_dict(self, state_dict: dict[str, Any]) -> None:
        """BenchMARL hook (unused)."""

    def on_batch_collected(self, batch: Any) -> None:
        """Counts the batch's frames and the time since the last training ended as collection."""
        self.collection_s += time.perf_counter() - self.last
        self.frames += int(batch.numel())

    def _entry(self, label: str, elapsed: float, state: dict[str, Any]) -> dict[str, Any]:
        return {"label": label, "frames": self.frames, "agent_steps": N_AGENTS * self.frames,
                "train_s": round(elapsed, 2), "collection_s": round(self.collection_s, 2), "state": state}

    def on_train_end(self, training_td: Any, group: str) -> None:
        """Keeps the policy for the budgets this batch reaches; raises :class:`StopTraining` after the last."""
        elapsed = time.perf_counter() - self.start
        state = copy.deepcopy(self.experiment.policy.state_dict())
        for f in self.frame_budgets:
            label = f"frames{f}"
            if self.frames >= f and label not in self.kept:
                self.kept[label] = self._entry(label, elapsed, state)
        for s in self.second_budgets:
            label = f"seconds{s:g}"
            if elapsed <= s:
                self.pending[label] = self._entry(label, elapsed, state)
            elif label in self.pending:
                self.kept[label] = self.pending.pop(label)
        self.last = time.perf_counter()
        done = self.frames >= max(self.frame_budgets) and elapsed >= max(self.second_budgets)
        if done or elapsed >= self.max_seconds:
            self.total = {"frames": self.frames, "agent_steps": N_AGENTS * self.frames, "train_s": round(elapsed, 2),
                          "collection_s": round(self.collection_s, 2), "capped": not done}
            if not done:  # what the run reached by the time cap
                self.kept["capped"] = self._entry("capped", elapsed, state)
            raise StopTraining

    def save(self) -> list[dict[str, Any]]:
        """Writes the kept policies (``torch.save`` of the policy's state dict); their rows."""
        import torch

        for label, entry in self.pending.items():  # the run ended within these wall-time budgets
            self.kept.setdefault(label, entry)
        rows = []
        for label, entry in self.kept.items():
            torch.save(entry["state"], self.out / f"policy_{label}.pt")
            rows.append({k: v for k, v in entry.items() if k != "state"})
        return rows


def train(argv: Sequence[str]) -> dict[str, Any]:
    """The ``train`` command; writes and returns ``train.json``."""
    import os

    p = argparse.ArgumentParser(prog="benchmarl_venv.py train")
    p.add_argument("--algo", required=True, choices=["mappo", "ippo"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="folder for the kept policies and train.json")
    p.add_argument("--frame-budgets", type=int, nargs="+", required=True, help="env (team) steps")
    p.add_argument("--second-budgets", type=float, nargs="+", required=True)
    p.add_argument("--max-seconds", type=float, required=True, help="stop here even if a budget is not reached")
    p.add_argument("--frames-per-batch", type=int, default=None)
    args = p.parse_args(list(argv))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    callback = BudgetCallback(out, args.frame_budgets, args.second_budgets, args.max_seconds)
    experiment = build_experiment(args.algo, args.seed, str(out), args.frames_per_batch, [callback])
    load_start = os.getloadavg()
    callback.begin()
    with contextlib.suppress(StopTraining):
        experiment.run()
    kept = callback.save()
    config = experiment.config
    result = {"algo": args.algo, "seed": args.seed, "kept": kept, "total": callback.total,
              "max_seconds": args.max_seconds, "frame_budgets": args.frame_budgets,
              "load_start": [round(x, 2) for x in load_start], "load_end": [round(x, 2) for x in os.getloadavg()],
              "settings": {"frames_per_batch": config.on_policy_collected_frames_per_batch,
                           "n_envs": config.on_policy_n_envs_per_worker,
                           "minibatch_iters": config.on_policy_n_minibatch_iters,
                           "minibatch_size": config.on_policy_minibatch_size, "lr": config.lr, "gamma": config.gamma,
                           "share_policy_params": config.share_policy_params,
                           "continuous_actions": experiment.continuous_actions}}
    (out / "train.json").write_text(json.dumps(result, indent=1))
    return result


def evaluate(argv: Sequence[str]) -> dict[str, Any]:
    """The ``eval`` command: every ``--policies`` file, greedy, on ``-n`` episodes from ``--seed``."""
    import tempfile

    import torch
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    p = argparse.ArgumentParser(prog="benchmarl_venv.py eval")
    p.add_argument("--algo", required=True, choices=["mappo", "ippo"])
    p.add_argument("--policies", nargs="+", required=True)
    p.add_argument("-n", "--n-episodes", type=int, default=1000)
    p.add_argument("--seed", type=int, default=10_000)
    args = p.parse_args(list(argv))
    with tempfile.TemporaryDirectory() as tmp:
        experiment = build_experiment(args.algo, 0, tmp, None)
        policy = experiment.policy
        (group,) = experiment.group_map  # simple_spread: one group of 3 agents

        def act(obs: np.ndarray) -> np.ndarray:
            n = len(obs)
            td = TensorDict({group: TensorDict({"observation": torch.as_tensor(obs, dtype=torch.float32)},
                                               batch_size=[n, N_AGENTS])}, batch_size=[n])
            with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
                return policy(td)[group, "action"].numpy()

        results = {}
        for path in args.policies:
            policy.load_state_dict(torch.load(path, weights_only=True))
            returns = spread_episodes(act, args.n_episodes, args.seed)
            results[Path(path).name] = {"mean_return": float(np.mean(returns)), "std_return": float(np.std(returns)),
                                        "n_episodes": len(returns)}
        experiment.close()
    return results


def collect(argv: Sequence[str]) -> dict[str, Any]:
    """The ``collect`` command: BenchMARL's collector (MAPPO's policy, its default 10 serial envs) gathering one
    batch of ``--frames`` env steps after an untimed one; agent steps per second."""
    import tempfile

    p = argparse.ArgumentParser(prog="benchmarl_venv.py collect")
    p.add_argument("--frames", type=int, default=1200, help="env steps of the timed batch")
    args = p.parse_args(list(argv))
    with tempfile.TemporaryDirectory() as tmp:
        experiment = build_experiment("mappo", 0, tmp, args.frames)
        batches = iter(experiment.collector)
        next(batches)  # warm-up
        start = time.perf_counter()
        frames = int(next(batches).numel())
        seconds = time.perf_counter() - start
        experiment.close()
    return {"frames": frames, "seconds": seconds, "agent_steps_per_s": N_AGENTS * frames / seconds}


COMMANDS: dict[str, Callable[[Sequence[str]], dict[str, Any]]] = {"train": train, "eval": evaluate,
                                                                   "collect": collect}


def main(argv: Sequence[str]) -> None:
    """``train``, ``eval`` or ``collect`` and its options; prints the result as one JSON line."""
    if not argv or argv[0] not in COMMANDS:
        raise SystemExit(f"usage: benchmarl_venv.py {'|'.join(COMMANDS)} [options]")
    result = COMMANDS[argv[0]](argv[1:])
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
