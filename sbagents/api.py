"""The Python API in one import: what the CLIs call, for your own scripts and notebooks::

    from sbagents.api import ExecOptions, RunRef, TrainSpec, evaluate, train

    result = train(TrainSpec("ppo", "sbagents/GridWorld-v0", n_timesteps=20_000), execution=ExecOptions(seed=0))
    print(result.run_dir, evaluate(RunRef("ppo", "sbagents/GridWorld-v0"))["mean_return"])   # 93.0
"""

from sbagents.core.lifecycle import TrainResult
from sbagents.core.options import (
    EvalOptions,
    EvaluateOptions,
    ExecOptions,
    OutputOptions,
    StudyOptions,
    TrainSpec,
)
from sbagents.core.run_dir import RunRef
from sbagents.deploy.exporting import export, export_groups
from sbagents.federated.personal import personalize
from sbagents.federated.runner import federate
from sbagents.federated.settings import FederatedSettings
from sbagents.pipeline.backends import evaluate, train
from sbagents.pipeline.trust import TrustOptions
from sbagents.pipeline.tuning import tune
from sbagents.private.options import PrivacyOptions
from sbagents.visualize.curves import plot
from sbagents.visualize.video import record_video

__all__ = [
    "EvalOptions",
    "EvaluateOptions",
    "ExecOptions",
    "FederatedSettings",
    "OutputOptions",
    "PrivacyOptions",
    "RunRef",
    "StudyOptions",
    "TrainResult",
    "TrainSpec",
    "TrustOptions",
    "evaluate",
    "export",
    "export_groups",
    "federate",
    "personalize",
    "plot",
    "record_video",
    "train",
    "tune",
]
