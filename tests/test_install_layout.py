"""sbagents imports from a source checkout as from a wheel (``sbagents/envs`` etc. are links to the root folders),
and writes its caches to the user's cache folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from cli_helpers import REPO

#: Drop setuptools' editable finder (if this checkout is installed editable), so only the checkout itself is seen.
NO_EDITABLE = (
    "import sys\n"
    "sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in type(f).__module__.lower()]\n"
    "sys.path_hooks[:] = [h for h in sys.path_hooks if 'editable' not in getattr(h, '__module__', '').lower()]\n"
)


def _python(code: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=120,
                          env={**os.environ, **(env or {})})


def test_checkout_maps_envs_callbacks_and_configs(tmp_path: Path) -> None:
    code = NO_EDITABLE + (
        f"sys.path.insert(0, {str(REPO)!r})\n"
        "import sbagents, sbagents.callbacks, sbagents.envs.kuka, sbagents.zoo_configs\n"
        "from sbagents.core.zoo_config import default_config_path\n"
        "for m in (sbagents, sbagents.callbacks, sbagents.envs.kuka):\n"
        "    print(m.__file__)\n"
        "print(default_config_path('ppo'))\n"
    )
    result = _python(code, tmp_path)
    assert result.returncode == 0, result.stderr
    files = [Path(line).resolve() for line in result.stdout.splitlines()]
    assert files == [(REPO / "sbagents" / "__init__.py").resolve(), (REPO / "callbacks" / "__init__.py").resolve(),
                     REPO / "envs" / "kuka" / "__init__.py", REPO / "zoo_configs" / "ppo.yml"]


def test_numba_cache_goes_to_the_user_cache_folder(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    package = Path(__import__("sbagents.batched", fromlist=["x"]).__file__).parent
    before = sorted(package.rglob("*.nb[ic]"))
    code = (
        "from sbagents.batched import make_batched_vec_env\n"
        "import numpy as np\n"
        "venv = make_batched_vec_env('sbagents/GridWorld-v0', 2, 0, {}, None)\n"
        "venv.reset(); venv.step(np.array([1, 3]))\n"
        "import numba.core.config as c; print(repr(c.CACHE_DIR))\n"
    )
    result = _python(code, tmp_path, {"SBAGENTS_CACHE_DIR": str(cache)})
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "''"  # numba's own setting is left as it was
    assert list((cache / "numba").rglob("*.nbi")), "no compiled kernel was cached"
    assert sorted(package.rglob("*.nb[ic]")) == before, "numba wrote its cache into the package"
