"""The Python API in one import: what the CLIs call, for your own scripts and notebooks::

    from sbagents.api import ExecOptions, RunRef, TrainSpec, evaluate, train

    result = train(TrainSpec("ppo", "sbagents/GridWorld-v0", n_timesteps=20_000), execution=ExecOptions(seed=0))
    print(result.run_dir, evaluate(RunRef("ppo", "sbagents/GridWorld-v0"))["mean_return"])   # 93.0
"""

from sbagents.callbacks.extension import TrustOptions
from sbagents.constrained.options import ConstraintSpec
from sbagents.core.extensions import TrainingExtension, register_extension
from sbagents.core.lifecycle import TrainResult
from sbagents.core.options import (
    EvalOptions,
    EvaluateOptions,
    ExecOptions,
    OutputOptions,
    RllibOptions,
    Sb3Options,
    StudyOptions,
    TrainSpec,
)
from sbagents.core.run_dir import RunRef
from sbagents.deploy.exporting import export, export_groups
from sbagents.federated.personal import personalize
from sbagents.federated.runner import federate
from sbagents.federated.settings import FederatedSettings
from sbagents.pipeline.backends import evaluate, train
from sbagents.pipeline.tuning import tune
from sbagents.private.options import PrivacyOptions
from sbagents.replay.extension import ReplayBufferOptions
from sbagents.robust.options import RobustSpec, parse_robust
from sbagents.visualize.curves import plot
from sbagents.visualize.video import record_video

__all__ = [
    "ConstraintSpec",
    "EvalOptions",
    "EvaluateOptions",
    "ExecOptions",
    "FederatedSettings",
    "OutputOptions",
    "PrivacyOptions",
    "ReplayBufferOptions",
    "RllibOptions",
    "RobustSpec",
    "RunRef",
    "Sb3Options",
    "StudyOptions",
    "TrainResult",
    "TrainSpec",
    "TrainingExtension",
    "TrustOptions",
    "evaluate",
    "export",
    "export_groups",
    "federate",
    "parse_robust",
    "personalize",
    "plot",
    "record_video",
    "register_extension",
    "train",
    "tune",
]
