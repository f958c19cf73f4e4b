"""What every loader of files from someone else shares: the trust flag and its one-line refusal.

sbagents decodes no pickle from a file unless the user passes :data:`TRUST_FLAG`: models are rebuilt from numbers,
names and weights (:mod:`sbagents.safe_load`), statistics and buffers are ``.npz`` files read without pickles
(:mod:`sbagents.state_files`). A file that would need more raises :class:`UntrustedContentError`.
"""

from __future__ import annotations

from sbagents.errors import UsageError

#: The flag of every CLI that loads files from a run dir: trust them (load pickles as they are).
TRUST_FLAG = "--trust-run"


class UntrustedContentError(UsageError):
    """A file holds something that loading it would have to execute; the message names it and the trust flag."""


def short_message(exc: BaseException, limit: int = 160) -> str:
    """``exc``'s message on one line, at most ``limit`` characters."""
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
