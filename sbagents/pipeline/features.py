"""The built-in training extensions, registered in this order when the pipeline is imported (the order of their
hooks and of their ``--help`` groups); user extensions registered later follow them."""

from __future__ import annotations

from sbagents.callbacks.extension import TrustExtension
from sbagents.constrained.extension import ConstraintExtension
from sbagents.extensions import TrainingExtension, register_extension, registered_extensions, unregister_extension
from sbagents.private.extension import PrivacyExtension
from sbagents.replay.extension import ReplayBufferExtension
from sbagents.robust.extension import RobustExtension

#: Built-in extensions, in hook order.
BUILTIN_EXTENSIONS: tuple[TrainingExtension, ...] = (
    ReplayBufferExtension(), PrivacyExtension(), RobustExtension(), ConstraintExtension(), TrustExtension())


def register_builtin_extensions() -> None:
    """Register the built-in extensions ahead of any registered before (idempotent)."""
    users = [ext for ext in registered_extensions() if ext.name not in {b.name for b in BUILTIN_EXTENSIONS}]
    for ext in [*BUILTIN_EXTENSIONS, *users]:
        unregister_extension(ext.name)
        register_extension(ext)

