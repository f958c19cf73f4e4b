"""Importing sbagents from a source checkout as well as from a wheel.

The repository keeps ``envs/``, ``callbacks/`` and ``zoo_configs/`` beside ``sbagents/``; a wheel (or an
editable install) maps them to ``sbagents.envs``, ``sbagents.callbacks`` and ``sbagents.zoo_configs``
(setuptools ``package-dir``). When Python imports ``sbagents`` straight from a checkout (``python -m
sbagents.train`` run in the repository root puts the checkout first on ``sys.path``, ahead of any
installed copy), :func:`install` maps those three names to the sibling folders, as setuptools' own editable
finder does. An installed package, whose subpackages sit inside it, is left alone.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

#: Subpackage name -> folder of the repository root that holds it.
SIBLING_PACKAGES: dict[str, str] = {
    "sbagents.envs": "envs",
    "sbagents.callbacks": "callbacks",
    "sbagents.zoo_configs": "zoo_configs",
}


class SiblingPackageFinder(importlib.abc.MetaPathFinder):
    """Finds the :data:`SIBLING_PACKAGES` of one source checkout (their submodules then follow ``__path__``).

    :param root: the repository root (the folder holding ``sbagents/``, ``envs/``, ...).
    """

    def __init__(self, root: Path) -> None:
        self.root = root

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        folder = SIBLING_PACKAGES.get(fullname)
        if folder is None:
            return None
        package = self.root / folder
        return importlib.util.spec_from_file_location(
            fullname, package / "__init__.py", submodule_search_locations=[str(package)]
        )


def install(package_dir: Path) -> bool:
    """Map the sibling folders when ``package_dir`` (the imported ``sbagents/``) sits in a source checkout.

    :return: whether a finder was installed (False for an installed package, or when one is in place).
    """
    root = package_dir.parent
    if (package_dir / "envs").is_dir() or not all(
        (root / folder / "__init__.py").is_file() for folder in SIBLING_PACKAGES.values()
    ):
        return False
    if any(isinstance(f, SiblingPackageFinder) and f.root == root for f in sys.meta_path):
        return False
    sys.meta_path.insert(0, SiblingPackageFinder(root))
    return True
