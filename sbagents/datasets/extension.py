"""``train --pretrain DATASET``: behaviour cloning of the policy from a Minari dataset before reinforcement learning,
as a training extension (:mod:`sbagents.extensions`)."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import sync_envs_normalization

from sbagents.core.env_kinds import GAME, SINGLE_AGENT, TEAM
from sbagents.core.extensions import Contribution, ExtensionPlan, SpecRecord, TrainingContext, TrainingExtension
from sbagents.errors import UsageError

#: Episodes the pretrained policy is evaluated on before learning starts.
PRETRAINED_EVAL_EPISODES = 5


@dataclass(frozen=True)
class PretrainSpec:
    """Behaviour cloning before RL.

    :param dataset: the Minari dataset id (its spaces must be the env's; "": only the groups of ``by_group``).
    :param by_group: (group, dataset id) pairs of a run of one model per group: that group's model is cloned from
        that dataset (its spaces must be the group's); groups without one take ``dataset`` (or none when "").
    :param steps: gradient steps (shuffled batches, as many passes over the pairs as that takes).
    :param batch_size: pairs per gradient step.
    :param learning_rate: Adam's step size.
    :param holdout: share of the pairs kept out of training to report the loss on.
    """

    dataset: str
    steps: int = 2000
    batch_size: int = 256
    learning_rate: float = 1e-3
    holdout: float = 0.1
    by_group: tuple[tuple[str, str], ...] = ()

    def dataset_for(self, group: str | None) -> str | None:
        """The dataset of the model of ``group`` (None: the run's one model); None: that model is not cloned."""
        return (dict(self.by_group).get(group) if group is not None else None) or self.dataset or None

    def validate(self) -> None:
        """One line for a setting out of range."""
        if self.steps < 1 or self.batch_size < 1 or not self.learning_rate > 0 or not 0 <= self.holdout < 1:
            raise UsageError("--pretrain: steps and batch size must be >= 1, the learning rate > 0 and the held-out "
                             f"share in [0, 1); got {self.steps}, {self.batch_size}, {self.learning_rate}, "
                             f"{self.holdout}")


class PretrainExtension(TrainingExtension[PretrainSpec]):
    """``--pretrain DATASET`` (``--pretrain-steps N``): clone the dataset's actions into the new model's policy
    (:func:`sbagents.datasets.cloning.clone`), print the held-out loss and the pretrained policy's return (one line,
    before learning starts), then learn; ``summary.json``'s ``pretrain`` item."""

    name = "pretrain"
    title = "learning from data (behaviour cloning; pip install 'sbagents[data]')"
    flags = "--pretrain"
    spec_type = PretrainSpec
    group_runs = True  # one model per group: --pretrain GROUP=DATASET for each group (spaces differ by group)
    algos = ("a2c", "ppo", "trpo", "ppo_mask", "sac", "tqc", "td3", "ddpg", "dqn", "qrdqn")
    kinds = (SINGLE_AGENT.name, TEAM.name, GAME.name)

    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--pretrain", action="append", default=None, metavar="[GROUP=]DATASET",
                           help="behaviour-clone the policy from this Minari dataset (namespace/name-vN) before RL; "
                                "GROUP=DATASET (repeated) clones a group's model in a run of one model per group")
        group.add_argument("--pretrain-steps", type=int, default=PretrainSpec.steps, metavar="N",
                           help=f"gradient steps of behaviour cloning (default {PretrainSpec.steps}, batches of "
                                f"{PretrainSpec.batch_size})")

    def from_args(self, args: argparse.Namespace) -> PretrainSpec | None:
        if args.pretrain is None:
            if args.pretrain_steps != PretrainSpec.steps:
                raise UsageError("--pretrain-steps applies to --pretrain DATASET")
            return None
        plain = [item for item in args.pretrain if "=" not in item]
        pairs = [tuple(item.split("=", 1)) for item in args.pretrain if "=" in item]
        if len(plain) > 1 or any(not g or not d for g, d in pairs) or len({g for g, _ in pairs}) < len(pairs):
            raise UsageError("--pretrain takes one DATASET for every model, and GROUP=DATASET once per group; got "
                             + " ".join(args.pretrain))
        return PretrainSpec(plain[0] if plain else "", steps=args.pretrain_steps,
                            by_group=tuple((str(g), str(d)) for g, d in pairs))

    def configure(self, spec: PretrainSpec | None, plan: ExtensionPlan) -> PretrainSpec | None:
        if spec is not None:
            if plan.resuming:
                raise UsageError("--pretrain clones into a new model; -i continues a trained one (its weights would "
                                 "be overwritten): drop --pretrain to continue a run")
            unknown = sorted({g for g, _ in spec.by_group} - set(plan.groups))
            if unknown:
                where = f"its groups are {', '.join(plan.groups)}" if plan.groups else "it trains one model"
                raise UsageError(f"--pretrain GROUP=DATASET names the groups of a run of one model per group: "
                                 f"{', '.join(unknown)} is not one of this run's ({plan.ref.env_id}: {where})")
            from sbagents.datasets.writing import require_minari

            require_minari()
        return spec

    def callbacks(self, spec: PretrainSpec, ctx: TrainingContext) -> list[BaseCallback]:
        from sbagents.datasets.cloning import clone
        from sbagents.datasets.reading import load_transitions

        dataset = spec.dataset_for(ctx.group)
        if dataset is None:  # a group without a dataset of its own learns from scratch
            return []
        data = load_transitions(dataset, ctx.model.observation_space, ctx.model.action_space)
        result = clone(ctx.model, data, steps=spec.steps, batch_size=spec.batch_size,
                       learning_rate=spec.learning_rate, holdout=spec.holdout, seed=ctx.seed)
        # a group's model acts only beside the other groups: the team is evaluated after training, not before
        item: dict[str, Any] = {"dataset": dataset, **asdict(result), "steps": spec.steps,
                                "eval_return": _pretrained_return(ctx) if ctx.group is None else None}
        if ctx.group is not None:
            item["group"] = ctx.group
        ctx.state[self.name] = item
        print(_line(item), flush=True)  # before learning (and its progress bar) starts
        return []

    def finish(self, spec: PretrainSpec, ctx: TrainingContext) -> dict[str, Any]:
        item = ctx.state.get(self.name)
        return {"pretrain": item} if item else {}

    def record(self, spec: PretrainSpec) -> SpecRecord:
        given = ([spec.dataset] if spec.dataset else []) + [f"{g}={d}" for g, d in spec.by_group]
        return SpecRecord(args={"pretrain": given[0] if len(given) == 1 else given},
                          flags=[*(w for item in given for w in ("--pretrain", item)),
                                 *(["--pretrain-steps", str(spec.steps)] if spec.steps != PretrainSpec.steps else [])])


def _pretrained_return(ctx: TrainingContext) -> float:
    """The cloned policy's mean return over :data:`PRETRAINED_EVAL_EPISODES` greedy episodes."""
    from sbagents.callbacks.episodes import model_actor, play_episodes, summarize_records

    venv = ctx.make_eval_env(1, ctx.seed + 50_000)
    try:
        if ctx.model.get_vec_normalize_env() is not None:
            sync_envs_normalization(ctx.train_env, venv)
        records = play_episodes(venv, model_actor(ctx.model, ctx.exp.deterministic_eval), PRETRAINED_EVAL_EPISODES,
                                monitor_episodes=True)
    finally:
        venv.close()
    return float(summarize_records(records)["mean_return"])


def _line(item: Mapping[str, Any]) -> str:
    """``pretrained on sbagents/x-v0 (900 pairs, 2000 steps): training loss 0.1, held-out loss 0.12; before RL: ...``"""
    held = "" if item.get("holdout_loss") is None else f", held-out loss {item['holdout_loss']:.4g}"
    before = ("" if item.get("eval_return") is None else
              f"; before RL: mean return {item['eval_return']:.2f} over {PRETRAINED_EVAL_EPISODES} episodes")
    who = f"group {item['group']} " if item.get("group") else ""
    return (f"{who}pretrained on {item['dataset']} ({item['n_train']} pairs, {item['steps']} steps): training loss "
            f"{item['train_loss']:.4g}{held}{before}")


@dataclass(frozen=True)
class DemoSpec:
    """Demonstrations in an off-policy model's replay buffer (:mod:`sbagents.datasets.demos`).

    :param dataset: the Minari dataset id (its spaces must be the env's).
    :param ratio: the share of every batch drawn from the demonstrations.
    :param bc_weight: the factor of the supervised loss on demonstrations (0: none): behaviour cloning behind a
        Q-filter for actor-critic algorithms, DQfD's margin loss for DQN and QR-DQN
        (:mod:`sbagents.datasets.demo_losses`).
    :param filter_after: the model's gradient steps before the cloning loss's Q-filter starts (until then every
        demonstration counts; a run continued with ``-i`` counts on from its model's steps).
    """

    dataset: str
    ratio: float = 0.25
    bc_weight: float = 0.0
    filter_after: int = 10_000

    def validate(self) -> None:
        """One line for a setting out of range."""
        if not 0 <= self.ratio <= 1 or not self.bc_weight >= 0 or self.filter_after < 0:
            raise UsageError(f"--demos: the ratio must be in [0, 1], the BC weight and the filter's start >= 0; got "
                             f"{self.ratio}, {self.bc_weight}, {self.filter_after}")


class DemosExtension(TrainingExtension[DemoSpec]):
    """``--demos DATASET`` (``--demo-ratio R``, ``--demo-bc WEIGHT``): the dataset's transitions stay in the replay
    buffer and make up a set share of every batch (HER relabels them in goal envs), with an optional supervised loss on
    them; prints one line before learning; ``summary.json``'s ``demos`` item."""

    name = "demos"
    title = "learning from demonstrations (off-policy; pip install 'sbagents[data]')"
    flags = "--demos"
    spec_type = DemoSpec
    group_runs = False
    algos = ("sac", "tqc", "td3", "ddpg", "dqn", "qrdqn")
    kinds = (SINGLE_AGENT.name,)

    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--demos", default=None, metavar="DATASET",
                           help="keep this Minari dataset's transitions in the replay buffer (off-policy algorithms)")
        group.add_argument("--demo-ratio", type=float, default=DemoSpec.ratio, metavar="R",
                           help=f"share of every batch drawn from the demonstrations (default {DemoSpec.ratio})")
        group.add_argument("--demo-bc", type=float, default=DemoSpec.bc_weight, metavar="WEIGHT",
                           help="weight of a supervised loss on the demonstrations: behaviour cloning behind a "
                                "Q-filter (actor-critic), DQfD's margin loss (DQN); default 0: none")
        group.add_argument("--demo-filter-after", type=int, default=DemoSpec.filter_after, metavar="N",
                           help="gradient steps of the model before the cloning loss's Q-filter starts (default "
                                f"{DemoSpec.filter_after:,}; until then every demonstration counts)")

    def from_args(self, args: argparse.Namespace) -> DemoSpec | None:
        if args.demos is None:
            if (args.demo_ratio, args.demo_bc, args.demo_filter_after) != (DemoSpec.ratio, DemoSpec.bc_weight,
                                                                            DemoSpec.filter_after):
                raise UsageError("--demo-ratio, --demo-bc and --demo-filter-after apply to --demos DATASET")
            return None
        return DemoSpec(args.demos, ratio=args.demo_ratio, bc_weight=args.demo_bc,
                        filter_after=args.demo_filter_after)

    def configure(self, spec: DemoSpec | None, plan: ExtensionPlan) -> DemoSpec | None:
        if spec is not None:
            from sbagents.datasets.demos import demo_buffer_class
            from sbagents.datasets.writing import require_minari

            require_minari()
            demo_buffer_class(plan.exp.algo_kwargs.get("replay_buffer_class"))  # one line for a buffer of its own
            if int(plan.exp.algo_kwargs.get("n_steps", 1)) > 1:
                raise UsageError("--demos keeps one-step transitions; n_steps > 1 is not supported with it")
        return spec

    def contribute(self, spec: DemoSpec, plan: ExtensionPlan) -> Contribution:
        from sbagents.datasets.demos import demo_buffer_class

        return Contribution(model_kwargs={
            "replay_buffer_class": demo_buffer_class(plan.exp.algo_kwargs.get("replay_buffer_class"))})

    def callbacks(self, spec: DemoSpec, ctx: TrainingContext) -> list[BaseCallback]:
        from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

        from sbagents.datasets.demo_losses import DemoLossCallback
        from sbagents.datasets.demos import DemoMixin, demo_buffer
        from sbagents.datasets.reading import load_episodes, transitions_of

        model = ctx.model
        if not isinstance(model, OffPolicyAlgorithm):
            raise UsageError(f"--demos needs an off-policy model, not a {type(model).__name__}")
        episodes = load_episodes(spec.dataset, model.observation_space, model.action_space, flag="--demos")
        demos = demo_buffer(model, episodes)  # one line when the model's buffer does not mix demonstrations
        assert isinstance(model.replay_buffer, DemoMixin)
        model.replay_buffer.attach_demos(demos, spec.ratio)
        item: dict[str, Any] = {"dataset": spec.dataset, "episodes": len(episodes),
                                "transitions": sum(len(e) for e in episodes), "ratio": spec.ratio,
                                "bc_weight": spec.bc_weight}
        ctx.state[self.name] = item
        kind = "margin" if isinstance(model.action_space, spaces.Discrete) else \
            f"BC (Q-filtered after {spec.filter_after:,} steps)"
        loss = f", {kind} loss weight {spec.bc_weight:g}" if spec.bc_weight > 0 else ""
        print(f"demonstrations: {item['episodes']} episodes ({item['transitions']} transitions) of {spec.dataset}, "
              f"{spec.ratio:g} of every batch{loss}", flush=True)
        if spec.bc_weight == 0:
            return []
        callback = DemoLossCallback(transitions_of(episodes), spec.bc_weight, filter_after=spec.filter_after,
                                    seed=ctx.seed)
        ctx.state[f"{self.name}.loss"] = callback
        return [callback]

    def finish(self, spec: DemoSpec, ctx: TrainingContext) -> dict[str, Any]:
        item = ctx.state.get(self.name)
        if not item:
            return {}
        callback = ctx.state.get(f"{self.name}.loss")
        if callback is not None:
            item = {**item, "loss_steps": callback.steps, "loss_kept": callback.kept}
        return {"demos": item}

    def record(self, spec: DemoSpec) -> SpecRecord:
        flags = ["--demos", spec.dataset]
        if spec.ratio != DemoSpec.ratio:
            flags += ["--demo-ratio", str(spec.ratio)]
        if spec.bc_weight != DemoSpec.bc_weight:
            flags += ["--demo-bc", str(spec.bc_weight)]
        if spec.filter_after != DemoSpec.filter_after:
            flags += ["--demo-filter-after", str(spec.filter_after)]
        return SpecRecord(args={"demos": spec.dataset, "demo_ratio": spec.ratio, "demo_bc": spec.bc_weight,
                                "demo_filter_after": spec.filter_after}, flags=flags)
