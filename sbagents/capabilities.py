"""What a feature supports, declared by the feature itself: :class:`Capability`, one column of the capability table
(:func:`sbagents.algos.capability_rows`, ``train --list``)."""

from __future__ import annotations

from dataclasses import dataclass

from sbagents.errors import UsageError


@dataclass(frozen=True)
class Capability:
    """What a feature supports: one column of the capability table (:func:`sbagents.algos.capability_rows`, ``train
    --list``), declared by the feature itself (a training extension, a backend, federated homes, the team kind's
    centralized critic).

    :param name: the column name (e.g. ``"dp"``, ``"robust:sa"``).
    :param description: what the column means (the legend of ``train --list``).
    :param algos: the ``--algo`` names it trains (None: any; such a capability adds no column).
    :param kinds: the env kinds it trains, by :attr:`~sbagents.core.env_kinds.EnvKind.name` (None: any).
    :param label: what its refusals call it (default: ``name``), e.g. ``"--robust sa"``.
    :param refusal: the refusal of an algorithm outside ``algos``, a :meth:`str.format` template of ``{label}``,
        ``{algos}`` (comma-separated) and ``{algo}``.
    """

    name: str
    description: str
    algos: tuple[str, ...] | None = None
    kinds: tuple[str, ...] | None = None
    label: str = ""
    refusal: str = "{label} trains {algos}, not {algo}"

    @property
    def subject(self) -> str:
        """What refusals call the capability."""
        return self.label or self.name

    def check_algo(self, algo: str) -> None:
        """Raise :class:`UsageError` (one line naming the accepted algorithms) unless the capability takes ``algo``."""
        if self.algos is not None and algo not in self.algos:
            raise UsageError(self.refusal.format(label=self.subject, algos=", ".join(self.algos), algo=algo))

    def check_kind(self, kind: str, env_id: str) -> None:
        """Raise :class:`UsageError` (one line naming the accepted kinds) unless the capability takes an env of the
        kind named ``kind`` (``env_id``: the env, for the message)."""
        if self.kinds is not None and kind not in self.kinds:
            raise UsageError(f"{self.subject} trains {' and '.join(self.kinds)} envs, not {kind} envs ({env_id})")
