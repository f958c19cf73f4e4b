"""Import paths from files are checked before anything is imported (sbagents.import_paths)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from sbagents.core.experiment import import_object
from sbagents.errors import UsageError
from sbagents.import_paths import resolve_path


@pytest.mark.parametrize("path", [
    "numpy.f2py.__main__.main",  # importing it runs f2py's command line
    "numpy.distutils.ccompiler.CCompiler",
    "numpy.conftest.pytest_configure",
    "stable_baselines3.__main__:main",
    "sbagents.dashboard.__main__:main",
    "gymnasium..wrappers.TimeLimit",
    "gymnasium.wrappers.Time Limit",
])
def test_refused_paths_import_nothing(path: str) -> None:
    program = (
        "import sys\n"
        "from sbagents.core.experiment import import_object\n"
        "from sbagents.errors import UsageError\n"
        "before = set(sys.modules)\n"
        "try:\n"
        f"    import_object({path!r}, 'env_wrapper')\n"
        "except UsageError as exc:\n"
        "    print('refused', str(exc).count(chr(10)))\n"
        "print(sorted(m for m in set(sys.modules) - before if 'f2py' in m or 'distutils' in m or 'conftest' in m\n"
        "             or m.endswith('__main__') and m != '__main__'))\n"
    )
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[:2] == ["refused 0", "[]"], done.stdout


def test_a_module_its_package_does_not_load_is_not_imported() -> None:
    """An allowed package's module that nothing imported is refused, not imported (its import could act)."""
    program = (
        "import sys\n"
        "from sbagents.import_paths import resolve_path\n"
        "from sbagents.errors import UsageError\n"
        "try:\n"
        "    resolve_path('gymnasium.utils.play.play', 'env_wrapper', ('gymnasium',))\n"
        "except UsageError as exc:\n"
        "    print('refused')\n"
        "print('gymnasium.utils.play' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=120)
    assert done.stdout.split() == ["refused", "False"], done.stdout + done.stderr


def test_allowed_classes_still_resolve() -> None:
    from gymnasium.wrappers import TimeLimit
    from stable_baselines3.common.atari_wrappers import AtariWrapper

    assert import_object("gymnasium.wrappers.TimeLimit", "env_wrapper") is TimeLimit
    assert import_object("AtariWrapper", "env_wrapper") is AtariWrapper
    assert import_object("torch.nn.ReLU", "activation_fn").__name__ == "ReLU"
    obj, trusted = resolve_path("sbagents.multiagent.relational:EntityAttentionFeatures", "features_extractor_class",
                                ("sbagents",))
    assert obj.__name__ == "EntityAttentionFeatures" and not trusted


def test_outside_the_allow_list_is_one_line() -> None:
    with pytest.raises(UsageError, match="outside the import allow-list"):
        import_object("os.system", "env_wrapper")
