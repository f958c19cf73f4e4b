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


def shadowing_folder(module: ModuleType | None = None) -> Path | None:
    """The folder Python imported as ``sbagents`` instead of the package, or None when ``sbagents`` is the package.

    After ``pip install -e`` (setuptools' editable finder, setuptools issue 3557), Python started in a folder that
    holds a folder named ``sbagents`` without ``__init__.py`` (the parent of a clone called ``sbagents``) imports that
    folder as a namespace package: the submodules still load through the finder, but ``sbagents/__init__.py`` never
    runs, so no env id is registered.

    :param module: the imported ``sbagents`` (default: ``sys.modules["sbagents"]``).
    """
    module = sys.modules.get("sbagents") if module is None else module
    if module is None or getattr(module, "__file__", None) is not None:
        return None
    paths = list(getattr(module, "__path__", None) or [])
    return Path(paths[0]).resolve() if paths else None


def shadowing_hint(folder: Path) -> str:
    """One line on why the folder ``folder`` shadows the package and what to do."""
    return (f"Python imported the folder {folder} as sbagents instead of the installed package, because it was "
            f"started in {folder.parent}, which holds a folder named sbagents (setuptools issue 3557, see the "
            "README); run it from another folder (e.g. cd into the clone), or reinstall with pip install -e "
            "'.[test]' --config-settings editable_mode=strict")
