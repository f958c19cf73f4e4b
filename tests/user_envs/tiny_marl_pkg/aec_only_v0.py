"""A turn-based (AEC-only) env module: ``env()`` and ``raw_env()`` but no ``parallel_env()`` (the relay, wrapped)."""

from __future__ import annotations

from tiny_marl_pkg.relay_v0 import env, raw_env

__all__ = ["env", "raw_env"]
