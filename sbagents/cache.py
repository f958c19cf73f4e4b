"""Where sbagents keeps files it generates once per machine (compiled numba kernels, generated URDFs).

Never inside the package or the source tree: a per-user cache folder (``~/.cache/sbagents`` on Linux, the
platform's equivalent elsewhere, via ``platformdirs``), or the folder named by ``SBAGENTS_CACHE_DIR``.
"""

from __future__ import annotations

import os
from pathlib import Path

import platformdirs

#: Environment variable that overrides the cache folder.
CACHE_ENV_VAR = "SBAGENTS_CACHE_DIR"


def cache_dir(*parts: str) -> Path:
    """The cache folder (or its subfolder ``parts``), created if missing.

    >>> cache_dir("numba").name
    'numba'
    """
    root = os.environ.get(CACHE_ENV_VAR) or platformdirs.user_cache_dir("sbagents", appauthor=False)
    path = Path(root).expanduser().joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path
