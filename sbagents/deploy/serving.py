"""The on-device decision loop: one JSON observation per line in -> one JSON action per line out.

Needs only numpy and onnxruntime: this module imports neither torch, SB3 nor gymnasium (the ONNX file from
:func:`sbagents.deploy.exporting.export_run` has normalization and action rescaling baked in).

Protocol:

- Input: each non-blank line is a JSON list of numbers (``obs_dim`` of them; a single integer for a
  Discrete observation), or a JSON object keyed by exactly the sidecar's ``obs_names``. Blank lines are
  skipped.
- Output: for every other line exactly one line: the action as a JSON list of floats (Box) or an int
  (Discrete), or ``{"error": "<reason>"}`` for a malformed line (bad JSON, wrong length, unknown or missing
  keys, non-numbers, NaN/inf). Serving goes on after an error. The output is flushed per line.
- CSV log: every served decision is appended as ``timestamp, <obs_names>, <action_names>`` (header written
  when the file is new or empty; LF line ends) and flushed per line.

The sidecar (``policy.json``, found next to the model unless given) supplies ``obs_names`` / ``action_names``;
without it only lists are accepted and columns are ``obs_i``/``action_i``.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TextIO

import numpy as np


class ServeError(ValueError):
    """A malformed observation line (reported to the client, serving continues)."""


class Policy:
    """An ONNX policy plus the names from its sidecar.

    :param model_path: ONNX file with input ``(batch, obs_dim)`` float32 (or ``(batch,)`` int64).
    :param meta_path: sidecar JSON; default ``policy.json`` next to the model, if it exists.
    :raises FileNotFoundError, ValueError: the model or sidecar cannot be loaded.
    """

    def __init__(self, model_path: str | Path, meta_path: str | Path | None = None) -> None:
        import onnxruntime as ort

        path = Path(model_path)
        self.path = path
        if not path.is_file():
            raise FileNotFoundError(f"model file not found: {path}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ValueError(f"invalid ONNX model {path}: {exc}".splitlines()[0]) from exc
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        self.discrete_obs = "int64" in inp.type
        shape = inp.shape[1:]
        if self.discrete_obs:
            self.obs_dim = 1
        elif all(isinstance(d, int) for d in shape):
            self.obs_dim = int(np.prod(shape)) if shape else 1
        else:
            raise ValueError(f"model input {inp.name} has a non-static observation shape {inp.shape}")
        self.obs_shape = tuple(int(d) for d in shape)
        out = self.session.get_outputs()[0]
        self.discrete_action = "int64" in out.type
        self.act_dim = 1 if self.discrete_action else int(np.prod([int(d) for d in out.shape[1:]] or [1]))
        meta = self._load_meta(path, meta_path)
        self.obs_names: tuple[str, ...] = tuple(
            meta.get("obs_names") or (f"obs_{i}" for i in range(self.obs_dim))
        )
        self.action_names: tuple[str, ...] = tuple(
            meta.get("action_names") or (f"action_{i}" for i in range(self.act_dim))
        )
        if len(self.obs_names) != self.obs_dim or len(self.action_names) != self.act_dim:
            raise ValueError(
                f"sidecar names ({len(self.obs_names)} obs, {len(self.action_names)} action) do not "
                f"match the model ({self.obs_dim} obs, {self.act_dim} action)"
            )

    @staticmethod
    def _load_meta(model_path: Path, meta_path: str | Path | None) -> dict[str, Any]:
        meta_file = Path(meta_path) if meta_path is not None else model_path.parent / "policy.json"
        if not meta_file.is_file():
            if meta_path is not None:
                raise FileNotFoundError(f"sidecar not found: {meta_file}")
            return {}
        try:
            meta = json.loads(meta_file.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"invalid sidecar {meta_file}: {exc}") from exc
        if not isinstance(meta, dict):
            raise ValueError(f"invalid sidecar {meta_file}: not a JSON object")
        return meta

    def parse(self, line: str) -> list[float]:
        """One observation line -> ``obs_dim`` finite numbers (raises :class:`ServeError`)."""
        try:
            value = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ServeError(f"bad JSON: {exc.msg}") from None
        if isinstance(value, dict):
            unknown = sorted(set(value) - set(self.obs_names))
            missing = [k for k in self.obs_names if k not in value]
            if unknown or missing:
                named = (("unknown", unknown), ("missing", missing))
                problems = [f"{what} keys {keys}" for what, keys in named if keys]
                raise ServeError(f"{', '.join(problems)}; expected {list(self.obs_names)}")
            value = [value[k] for k in self.obs_names]
        elif self.discrete_obs and not isinstance(value, list):
            value = [value]
        if not isinstance(value, list):
            raise ServeError("observation must be a JSON list or object")
        if len(value) != self.obs_dim:
            raise ServeError(f"expected {self.obs_dim} values, got {len(value)}")
        for v in value:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ServeError(f"not a finite number: {v!r}")
            if self.discrete_obs and float(v) != int(v):
                raise ServeError(f"discrete observation must be an integer, got {v!r}")
        return [float(v) for v in value]

    def act(self, obs: Sequence[float]) -> list[float] | int:
        """Action for one observation: a list of floats (Box) or an int (Discrete)."""
        x: np.ndarray
        if self.discrete_obs:
            x = np.asarray([int(obs[0])], dtype=np.int64)
        else:
            x = np.asarray(obs, dtype=np.float32).reshape((1, *self.obs_shape))
        action = self.session.run(None, {self.input_name: x})[0]
        if self.discrete_action:
            return int(np.asarray(action).reshape(-1)[0])
        return [float(a) for a in np.asarray(action).reshape(-1)]


class DecisionLog:
    """The CSV log of served decisions: ``timestamp, <obs_names>, <action_names>`` per decision, flushed per row.

    The header is written when the file is new or empty (appending to an existing log keeps one header); LF line
    ends. A context manager; ``path=None`` logs nothing.
    """

    def __init__(self, policy: Policy, path: str | Path | None) -> None:
        self._file: TextIO | None = None
        self._writer: Any = None
        if path is None:
            return
        path = Path(path)
        new = not path.exists() or path.stat().st_size == 0
        self._file = path.open("a", newline="")
        self._writer = csv.writer(self._file, lineterminator="\n")
        if new:
            self._writer.writerow(["timestamp", *policy.obs_names, *policy.action_names])
            self._file.flush()

    def write(self, obs: Sequence[float], action: list[float] | int) -> None:
        """Append one decision (a no-op without a file)."""
        if self._file is None:
            return
        stamp = datetime.now(timezone.utc).isoformat()  # noqa: UP017 (py3.10 target)
        acts = action if isinstance(action, list) else [action]
        self._writer.writerow([stamp, *obs, *acts])
        self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> DecisionLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def decide(policy: Policy, text: str, log: DecisionLog) -> tuple[bool, str]:
    """One observation (JSON text) -> ``(ok, reply JSON)``: the action, or ``{"error": reason}`` for malformed input.

    Served decisions are appended to ``log``.
    """
    try:
        obs = policy.parse(text)
    except ServeError as exc:
        return False, json.dumps({"error": str(exc)})
    action = policy.act(obs)
    log.write(obs, action)
    return True, json.dumps(action)


def serve(
    policy: Policy, lines: TextIO, out: TextIO, csv_path: str | Path | None = None
) -> tuple[int, int]:
    """Run the loop until ``lines`` ends.

    :return: ``(n_served, n_errors)``.
    """
    served = errors = 0
    with DecisionLog(policy, csv_path) as log:
        for line in lines:
            if not line.strip():
                continue
            ok, reply = decide(policy, line, log)
            out.write(reply + "\n")
            out.flush()
            served += ok
            errors += not ok
    return served, errors
