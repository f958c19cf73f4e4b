"""The training-extension API of ``python -m sbagents.train`` (:mod:`sbagents.core.extensions`, where it lives beside
the experiment it types): subclass :class:`TrainingExtension`, register it with :func:`register_extension`.
``docs/extending.md`` walks through it."""

from sbagents.core.extensions import (
    TAKEN,
    ActiveExtension,
    Capability,
    Contribution,
    ExtensionPlan,
    SpecRecord,
    TrainingContext,
    TrainingExtension,
    activate,
    extension_for,
    finite,
    prepare_extensions,
    refused_flags,
    register_extension,
    registered_extensions,
    specs_from_args,
    unregister_extension,
)

__all__ = [
    "TAKEN", "ActiveExtension", "Capability", "Contribution", "ExtensionPlan", "SpecRecord", "TrainingContext",
    "TrainingExtension", "activate", "extension_for", "finite", "prepare_extensions", "refused_flags",
    "register_extension", "registered_extensions", "specs_from_args", "unregister_extension",
]
