"""``--robust SPEC``: which robust training a run uses (parsed without importing torch).

Grammar: ``METHOD:EPS[,KEY=VALUE...]``, eps in the attacks' units (VecNormalize standard deviations, else the
observation Box range), reached by a linear ramp over the first ``ramp`` of training (default 0.5).

- ``sa:EPS`` -- the state-adversarial regularizer (:class:`~sbagents.robust.sa_regularizer.SATD3` /
  ``SADDPG``); keys ``kappa`` (penalty weight, default 0.1), ``steps`` (PGD steps, default 3), ``qdrop`` (weight of
  the critic-aware term ``Q(s, pi(s)) - min Q(s, pi(s~))``, default 0), ``ramp``. The defaults are the published
  recipe (docs/robust.md: with kappa 1 and 5 steps, the classes' own defaults, SmartHome's TD3 keeps 0.89 / 0.59
  success under PGD / critic attacks at eps 0.2; with these, 0.99 / 0.99 at the entry's ``robust_overrides``
  budget).
- ``adv:EPS`` -- adversarial rollouts (:class:`~sbagents.robust.adversarial_rollouts.AdvTD3` / ``AdvDDPG`` /
  ``AdvSAC``): a share of the training steps act on observations attacked by :mod:`sbagents.callbacks.attacks`;
  keys ``attack`` (``pgd`` default, ``fgsm``, ``critic``, ``uniform``, ``gaussian``), ``share`` (default 0.5),
  ``ramp``.
- ``sa+adv:EPS`` -- both (``SAAdvTD3`` / ``SAAdvDDPG``), every key of the two.

Examples: ``sa:0.2``, ``sa:0.3,kappa=2,qdrop=1``, ``adv:0.2,attack=critic,share=0.3``, ``sa+adv:0.3,attack=critic``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sbagents.capabilities import Capability
from sbagents.core.env_kinds import SINGLE_AGENT
from sbagents.errors import UsageError

#: Algorithms each robust method trains, by name (the declaration of
#: :class:`~sbagents.robust.extension.RobustExtension`: one column of the capability table per method).
ROBUST_ALGOS: dict[str, tuple[str, ...]] = {"sa": ("ddpg", "td3"), "adv": ("ddpg", "td3", "sac"),
                                            "sa+adv": ("ddpg", "td3")}
#: The env kinds robust training takes: single-agent envs (the adversary attacks one model's observations).
ROBUST_KINDS: tuple[str, ...] = (SINGLE_AGENT.name,)
_METHODS = {"sa": "state-adversarial regularizer", "adv": "adversarial rollouts", "sa+adv": "both"}
#: What each robust method supports (:data:`ROBUST_ALGOS`, :data:`ROBUST_KINDS`): the capability table's
#: ``robust:<method>`` columns.
ROBUST_METHODS: dict[str, Capability] = {
    method: Capability(f"robust:{method}", f"--robust {method} ({_METHODS[method]})", algos, ROBUST_KINDS,
                       label=f"--robust {method}")
    for method, algos in ROBUST_ALGOS.items()}
_ATTACKS = ("pgd", "fgsm", "critic", "uniform", "gaussian")
_SA_KEYS = {"kappa": "sa_kappa", "steps": "sa_pgd_steps", "qdrop": "sa_critic_weight"}
#: ``sa`` settings a spec that does not name them gets: the recipe docs/robust.md measures.
SA_DEFAULTS: dict[str, Any] = {"kappa": 0.1, "steps": 3}
_ADV_KEYS = {"attack": "adv_attack", "share": "adv_share"}
_USAGE = "expected METHOD:EPS[,KEY=VALUE...] with METHOD sa, adv or sa+adv (e.g. sa:0.2, adv:0.2,attack=critic)"


def _number(low: float, high: float, integer: bool = False) -> Callable[[str], float | int]:
    def parse(text: str) -> float | int:
        value = float(text)
        if not (math.isfinite(value) and low <= value <= high) or (integer and value != int(value)):
            raise ValueError
        return int(value) if integer else value

    return parse


_VALUES: dict[str, tuple[Callable[[str], Any], str]] = {
    "kappa": (_number(0.0, math.inf), "a number >= 0"),
    "qdrop": (_number(0.0, math.inf), "a number >= 0"),
    "steps": (_number(1, 1000, integer=True), "an integer in 1..1000"),
    "ramp": (_number(0.0, 1.0), "a number in [0, 1]"),
    "share": (_number(0.0, 1.0), "a number in [0, 1]"),
    "attack": (lambda t: _ATTACKS[_ATTACKS.index(t)], "one of " + ", ".join(_ATTACKS)),
}


@dataclass(frozen=True)
class RobustSpec:
    """A parsed ``--robust`` value.

    :param method: ``"sa"``, ``"adv"`` or ``"sa+adv"``.
    :param eps: the final perturbation radius trained against.
    :param options: the ``KEY=VALUE`` settings, as ``(key, parsed value)`` pairs.
    :param text: the flag's value as given (None for a spec built in Python: :meth:`flag_value` writes one).
    """

    method: str
    eps: float
    options: tuple[tuple[str, Any], ...] = ()
    text: str | None = None

    def flag_value(self) -> str:
        """The ``--robust`` value of this spec (recorded in ``args.yml``; :func:`parse_robust` reads it back)."""
        if self.text is not None:
            return self.text
        return f"{self.method}:{self.eps:g}" + "".join(f",{key}={value}" for key, value in self.options)

    def check_algo(self, algo: str) -> None:
        """Raise :class:`UsageError` (one line) when the method does not train ``algo``."""
        ROBUST_METHODS[self.method].check_algo(algo)

    def model_class(self, algo: str) -> Any:
        """The SB3 class that trains ``algo`` with this method (imports torch)."""
        from sbagents.robust import adversarial_rollouts as adv
        from sbagents.robust import sa_regularizer as sa

        classes: dict[str, dict[str, Any]] = {"sa": {"td3": sa.SATD3, "ddpg": sa.SADDPG},
                   "adv": {"td3": adv.AdvTD3, "ddpg": adv.AdvDDPG, "sac": adv.AdvSAC},
                   "sa+adv": {"td3": adv.SAAdvTD3, "ddpg": adv.SAAdvDDPG}}
        return classes[self.method][algo]

    def model_kwargs(self) -> dict[str, Any]:
        """Constructor keywords of :meth:`model_class`."""
        options = dict(self.options)
        kwargs: dict[str, Any] = {}
        for prefix, keys in (("sa", _SA_KEYS), ("adv", _ADV_KEYS)):
            if prefix in self.method.split("+"):
                kwargs[f"{prefix}_eps"] = self.eps
                kwargs.update({arg: options[key] for key, arg in keys.items() if key in options})
                if "ramp" in options:
                    kwargs[f"{prefix}_ramp_fraction"] = options["ramp"]
        return kwargs


def parse_robust(text: str, algo: str | None = None) -> RobustSpec:
    """``"sa:0.2,kappa=2"`` -> :class:`RobustSpec` (module docstring); :class:`UsageError` (one line) for anything
    else, or for an ``algo`` the method does not train."""
    method, sep, rest = text.partition(":")
    if method not in ROBUST_ALGOS or not sep:
        raise UsageError(f"--robust {text!r}: {_USAGE}")
    value, *items = rest.split(",")
    try:
        eps = float(value)
    except ValueError:
        eps = math.nan
    if not math.isfinite(eps) or eps <= 0:
        raise UsageError(f"--robust {text!r}: EPS must be a finite number > 0")
    allowed = {"ramp"} | (set(_SA_KEYS) if "sa" in method.split("+") else set()) | (
        set(_ADV_KEYS) if "adv" in method.split("+") else set())
    options: dict[str, Any] = {}
    for item in items:
        key, eq, raw = item.partition("=")
        if not eq or key not in allowed:
            raise UsageError(f"--robust {text!r}: unknown setting {item!r}; {method} takes "
                             + ", ".join(f"{k}=..." for k in sorted(allowed)))
        parse, expected = _VALUES[key]
        try:
            options[key] = parse(raw)
        except ValueError:
            raise UsageError(f"--robust {text!r}: {key} must be {expected}, got {raw!r}") from None
    if "sa" in method.split("+"):
        options = {**SA_DEFAULTS, **options}
    spec = RobustSpec(method, eps, tuple(options.items()), text)
    if algo is not None:
        spec.check_algo(algo)
    return spec
