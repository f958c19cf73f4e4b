"""The short summary a federated run (and a personal fine-tuning) prints."""

from __future__ import annotations

from typing import Any


def result_lines(result: Any, personal: Any = None) -> list[str]:
    """Lines for a :class:`~sbagents.federated.runner.FederatedResult` and an optional
    :class:`~sbagents.federated.personal.PersonalResult`."""
    s, fed = result.summary, result.summary.get("federated", {})
    lines = [f"run dir: {result.run_dir}" + ("  (interrupted)" if result.interrupted else "")]
    held = fed.get("held_out") or {}
    if held:
        lines.append(f"held-out homes: comfort {held['heldout_criterion_share']:.1%} of steps, "
                     f"success {held['heldout_success_rate']:.0%} of episodes")
    if s.get("eval"):
        e = s["eval"]
        share = e.get("metrics", {}).get("criterion_share")
        lines.append(f"final eval (random users, {e['n_episodes']} episodes): return {e['mean_return']:.1f}"
                     + (f", comfort {share:.1%}" if share is not None else ""))
    if fed.get("bytes_per_round_per_home"):
        lines.append(f"traffic: {fed['bytes_per_round_per_home'] / 1024:.1f} KiB per home per round "
                     "(parameters down and up)")
    if fed.get("dp_epsilon") is not None:
        lines.append(f"privacy: user-level epsilon {fed['dp_epsilon']:.2f} at delta {fed['dp_delta']:g}")
    lines.append(f"time: {s['train_seconds']:.0f} s, {fed.get('rounds', 0)} rounds x {fed.get('homes')} homes x "
                 f"{fed.get('local_steps')} steps")
    if personal is not None:
        lines.append(personal_line(personal))
    return lines


def personal_line(personal: Any) -> str:
    """``personalized (home 3): comfort 71.0% -> 98.9%, energy 0.52 -> 0.31 (run dir ...)``."""
    b, a = personal.before, personal.after
    return (f"personalized: comfort {b['criterion_share']:.1%} -> {a['criterion_share']:.1%}, energy "
            f"{b['mean_energy']:.3f} -> {a['mean_energy']:.3f} per step (run dir {personal.run_dir})")
