"""BenchMARL's side of ``benchmarl-spread``: its venv (``.venv-benchmarl/``, created on first use with CPU torch
and the mpe2 we use), one training run per algorithm and seed (``benchmarl_venv.py train`` run by that venv's
python) and the evaluation of the policies it kept (``benchmarl_venv.py eval``), plus the settings that differ
from ours."""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

from benchmarks.report import BENCHMARKS_DIR

REPO = BENCHMARKS_DIR.parent
#: The venv script (run by the BenchMARL venv's python).
VENV_SCRIPT = Path(__file__).resolve().with_name("benchmarl_venv.py")
ENV = "mpe2.simple_spread_v3"
N_AGENTS = 3
#: BenchMARL release the venv gets, and the torch / torchvision it is given (CPU torch; TorchRL accepts it).
BENCHMARL_VERSION = "1.5.2"
TORCH_PINS = ("torch==2.13.0", "torchvision==0.28.0")
#: BenchMARL's default on-policy frames (env steps) per batch.
FRAMES_PER_BATCH = 6000


def frame_budget(agent_steps: int, frames_per_batch: int = FRAMES_PER_BATCH) -> int:
    """Env (team) steps of the first BenchMARL batch at or past ``agent_steps`` agent steps (3 agents)."""
    if agent_steps <= 0 or frames_per_batch <= 0:
        raise ValueError(f"budgets must be positive, got {agent_steps} agent steps, {frames_per_batch} frames/batch")
    return math.ceil(agent_steps / N_AGENTS / frames_per_batch) * frames_per_batch


def team_to_mappo(team_return: float) -> float:
    """MAPPO's logged score of a team return: R = 2T - 75 (its reward counts self-collisions, sums over agents)."""
    return 2.0 * team_return - 75.0


def venv_python(venv: Path) -> Path:
    """The python of a venv."""
    return venv / "bin" / "python"


def ensure_venv(venv: Path) -> Path:
    """BenchMARL's venv, created on first use (CPU torch first, then BenchMARL and our mpe2 version); its python."""
    python = venv_python(venv)
    if python.exists():
        return python
    mpe2_version = metadata.version("mpe2")
    base = getattr(sys, "_base_executable", sys.executable)
    subprocess.run([base, "-m", "venv", str(venv)], check=True)
    constraints = venv / "constraints.txt"
    constraints.write_text("\n".join(TORCH_PINS) + "\n")
    pip = [str(python), "-m", "pip", "install", "-q"]
    subprocess.run([*pip, TORCH_PINS[0]], check=True)
    subprocess.run([*pip, "-c", str(constraints), f"benchmarl=={BENCHMARL_VERSION}", f"mpe2=={mpe2_version}"],
                   check=True)
    return python


def venv_versions(python: Path) -> dict[str, str]:
    """Versions of the BenchMARL venv's packages."""
    code = ("import json, importlib.metadata as m; print(json.dumps({p: m.version(p) for p in "
            "('benchmarl', 'torchrl', 'tensordict', 'torch', 'mpe2', 'pettingzoo')}))")
    return dict(json.loads(subprocess.run([str(python), "-c", code], capture_output=True, text=True,
                                          check=True).stdout))


def last_json(stdout: str) -> Any:
    """The last line of a command's output, as JSON."""
    lines = [line for line in stdout.splitlines() if line.startswith("{")]
    if not lines:
        raise RuntimeError("the command printed no JSON result")
    return json.loads(lines[-1])


def benchmarl_train_args(algo: str, seed: int, out: Path, agent_budgets: Sequence[int],
                         second_budgets: Sequence[float], max_seconds: float,
                         frames_per_batch: int | None = None) -> list[str]:
    """The venv script's ``train`` arguments for one run."""
    fpb = frames_per_batch or FRAMES_PER_BATCH
    frames = [frame_budget(b, fpb) for b in agent_budgets]
    args = ["train", "--algo", algo, "--seed", str(seed), "--out", str(out),
            "--frame-budgets", *map(str, frames), "--second-budgets", *(f"{s:g}" for s in second_budgets),
            "--max-seconds", f"{max_seconds:g}"]
    return args + (["--frames-per-batch", str(frames_per_batch)] if frames_per_batch else [])


def run_benchmarl(python: Path, algo: str, seed: int, work: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Train (or reuse, with ``--reuse``) one BenchMARL run and evaluate its kept policies."""
    out = work / f"benchmarl_{algo}_seed{seed}"
    train_json = out / "train.json"
    if not (args.reuse and train_json.exists()):
        out.mkdir(parents=True, exist_ok=True)
        cmd = [str(python), str(VENV_SCRIPT), *benchmarl_train_args(
            algo, seed, out, args.agent_budgets, args.second_budgets, args.max_seconds, args.frames_per_batch)]
        with (out / "stdout.log").open("w") as log:
            subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, check=True)
    train = json.loads(train_json.read_text())
    policies = [str(out / f"policy_{k['label']}.pt") for k in train["kept"]]
    cache = out / f"evals_n{args.n_eval}_seed{args.eval_seed}.json"
    evals = json.loads(cache.read_text()) if args.reuse and cache.exists() else {}
    if not all(Path(p).name in evals for p in policies):
        evals = last_json(subprocess.run([str(python), str(VENV_SCRIPT), "eval", "--algo", algo, "--policies",
                                          *policies, "-n", str(args.n_eval), "--seed", str(args.eval_seed)],
                                         capture_output=True, text=True, check=True).stdout)
        cache.write_text(json.dumps(evals))
    budgets = {f"frames{frame_budget(b, args.frames_per_batch or FRAMES_PER_BATCH)}": f"agent_steps{b}"
               for b in args.agent_budgets}
    for kept in train["kept"]:
        kept["budget"] = budgets.get(kept["label"], kept["label"])
        kept["team_return"] = round(evals[f"policy_{kept['label']}.pt"]["mean_return"], 3)
        kept["std_return"] = round(evals[f"policy_{kept['label']}.pt"]["std_return"], 3)
    return train


#: What differs between the two sides (BenchMARL's values from its default configs in the venv's release).
BENCHMARL_SETTINGS: dict[str, str] = {
    "network": "MLP 256-256, tanh, actor and critic separate",
    "parameter sharing": "one actor shared by the 3 agents (share_policy_params), one critic (share_param_critic)",
    "critic input": "MAPPO: the env's global state (all agents' observations); IPPO: the agent's own observation",
    "recurrent": "no",
    "normalization": "none (observations, advantages, values: normalize_advantage=False, no value normalization)",
    "batch": "6,000 env steps = 18,000 agent steps per iteration (10 serial envs x 600 steps)",
    "epochs / minibatches": "45 minibatches of 400 env steps (3 passes over the batch)",
    "lr": "5e-5 constant (Adam eps 1e-6), grad-norm clip 5, no value clipping",
    "gamma / lambda": "0.99 / 0.9",
    "clip / entropy": "0.2 / 0",
    "episode": "25 steps (max_cycles set to 25; BenchMARL's own default is 100)",
    "actions": "discrete, categorical (prefer_continuous_actions set to False)",
    "env": "mpe2 simple_spread_v3 through TorchRL's PettingZooEnv (PettingZoo 1.27 no longer has MPE: the script "
           "points TorchRL's task table at mpe2's module)",
}

