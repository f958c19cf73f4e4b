"""Telling a folder that shadows the package from the package itself.

The repository keeps ``envs/``, ``callbacks/`` and ``zoo_configs/`` beside ``sbagents/``; ``sbagents/envs``,
``sbagents/callbacks`` and ``sbagents/zoo_configs`` are symbolic links to them, so a checkout, an editable install,
a wheel, mypy and import-linter all see one package ``sbagents`` with those subpackages (no import hook).
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import ModuleType


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
