"""``--save-replay-buffer`` and ``-i``'s replay buffer as a training extension (:mod:`sbagents.extensions`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sbagents.algos import ALGOS
from sbagents.core.extensions import ExtensionPlan, SpecRecord, TrainingContext, TrainingExtension
from sbagents.errors import UsageError
from sbagents.replay.buffer_files import ReplayBufferCheckpoint, buffer_for, load_replay_buffer, save_replay_buffer


@dataclass(frozen=True, kw_only=True)
class ReplayBufferOptions:
    """What happens to an off-policy run's replay buffer.

    :param save: keep it in ``replay_buffer.npz`` (replaced at each checkpoint and at the end, also after Ctrl-C),
        which ``-i`` loads to continue (``--save-replay-buffer``). Whatever this says, ``-i`` continues with the
        buffer saved beside its model when it was saved at the model's step (the final model's); a checkpoint of
        another step starts with an empty buffer (one warning line).
    """

    save: bool = False


class ReplayBufferExtension(TrainingExtension[ReplayBufferOptions]):
    """Loads the buffer beside ``-i``'s model; with ``--save-replay-buffer`` saves it at checkpoints and at the end;
    ``summary.json``'s ``replay_buffer`` item and its console line."""

    name = "replay_buffer"
    title = "replay buffer (off-policy algorithms)"
    flags = "--save-replay-buffer"
    spec_type = ReplayBufferOptions

    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--save-replay-buffer", action="store_true",
                           help="off-policy: keep the replay buffer in the run dir (replay_buffer.npz, replaced at "
                                "each checkpoint and at the end, also after Ctrl-C) so that -i continues with it")

    def from_args(self, args: argparse.Namespace) -> ReplayBufferOptions | None:
        return ReplayBufferOptions(save=True) if args.save_replay_buffer else None

    def configure(self, spec: ReplayBufferOptions | None, plan: ExtensionPlan) -> ReplayBufferOptions:
        # every SB3 run takes part: -i continues with the buffer saved beside its model
        spec = spec or ReplayBufferOptions()
        if spec.save and (not ALGOS[plan.algo].off_policy or plan.n_models > 1):
            raise UsageError("--save-replay-buffer keeps the buffer of one off-policy model (dqn, ddpg, td3, sac, "
                             f"tqc, ...); {plan.algo} on {plan.ref.env_id} has none or trains one model per group")
        return spec

    def record(self, spec: ReplayBufferOptions) -> SpecRecord:
        return SpecRecord(flags=["--save-replay-buffer"] if spec.save else [])

    def callbacks(self, spec: ReplayBufferOptions, ctx: TrainingContext) -> list[BaseCallback]:
        loaded, reason = None, None
        if ctx.trained_agent is not None:
            _, reason = buffer_for(ctx.model, ctx.trained_agent)
            if reason is not None:  # before the progress bar draws: one plain line
                print(f"warning: {reason}", file=sys.stderr, flush=True)
            loaded = load_replay_buffer(ctx.model, ctx.trained_agent, ctx.trust_run)
        ctx.state[self.name] = (loaded, reason)
        if spec.save and ctx.save_freq > 0:
            return [ReplayBufferCheckpoint(ctx.run_dir, ctx.calls(ctx.save_freq))]
        return []

    def finish(self, spec: ReplayBufferOptions, ctx: TrainingContext) -> dict[str, Any]:
        if spec.save:
            save_replay_buffer(ctx.model, ctx.run_dir)
        loaded, reason = ctx.state.get(self.name, (None, None))
        if loaded is None and not spec.save and reason is None:
            return {}
        item: dict[str, Any] = {"loaded_transitions": loaded, "saved": spec.save}
        if reason is not None:
            item["not_loaded"] = reason
        return {"replay_buffer": item}

    def describe(self, summary: Mapping[str, Any], run_dir: Path) -> list[str]:
        buffer = summary.get("replay_buffer")
        if not buffer:
            return []
        loaded = buffer["loaded_transitions"]
        parts = ([] if loaded is None else [f"continued with the {loaded} transitions saved beside -i's model"]) + (
            ["-i's model has none of its own: started empty"] if buffer.get("not_loaded") else []) + (
            [f"saved in {run_dir}/replay_buffer.npz"] if buffer["saved"] else [])
        return ["replay buffer: " + "; ".join(parts)]
