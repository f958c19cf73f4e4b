"""The on-device decision loop: one JSON observation per line in -> one JSON action per line out.

Needs only numpy and onnxruntime: this module imports neither torch, SB3 nor gymnasium (the ONNX file from
:func:`sbagents.deploy.exporting.export_run` has normalization and action rescaling baked in).

Protocol:

- Input: each line is a JSON list of numbers (``obs_dim`` of them; a single integer for a Discrete
  observation), or a JSON object keyed by exactly the sidecar's ``obs_names``; UTF-8, at most
  :func:`request_limit` bytes (:data:`MAX_REQUEST_BYTES`; 32 bytes a value for a policy of more than 2,048
  observation values, such as an Atari frame stack).
- Output: for every line exactly one line: the action as a JSON list of floats (Box) or an int (Discrete), or
  ``{"error": "<reason>"}`` for a line that is not one observation (empty, too long, not UTF-8, bad or too deeply
  nested JSON, wrong length, unknown, missing or repeated keys, non-numbers, NaN/Infinity, numbers out of the
  float32 range or a Discrete observation outside the sidecar's range). Serving goes on after an error. The output
  is flushed per line.
- A recurrent policy (an ONNX graph with the state inputs ``state_h``, ``state_c``, ``episode_start`` that
  ``python -m sbagents.export`` writes for ``ppo_lstm``) keeps no memory in the server: the state travels in the
  request and the reply. A request is ``{"obs": <observation as above>, "state": <the "state" of the previous
  reply, or null at an episode start>}`` (``state`` may be left out at an episode start); the reply is
  ``{"action": <action>, "state": [<2 * n_layers * hidden numbers>]}``. So any number of clients, over stdin or
  HTTP, each carry their own episode; a wrong-length or non-finite state is an error reply like a bad observation.
- CSV log: every served decision is appended as ``timestamp, <obs_names>, <action_names>`` (header written
  when the file is new or empty; LF line ends) and flushed per line.

The sidecar (``policy.json``, found next to the model unless given) supplies ``obs_names`` / ``action_names`` (both
required in a sidecar: lists of distinct strings, as many as the model's observation and action values); without a
sidecar only lists are accepted and columns are ``obs_i``/``action_i``.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterator, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, BinaryIO, TextIO

import numpy as np

#: Longest observation line (stdin) or body (HTTP) accepted, in bytes; an observation is a few hundred.
MAX_REQUEST_BYTES = 64 * 1024
#: Bytes a request may spend per observation value when the observation is large (a float written in full, its
#: ``obs_names`` key, separators): see :func:`request_limit`.
REQUEST_BYTES_PER_VALUE = 32
#: Longest sidecar read; the exported ``policy.json`` is a few KiB.
MAX_SIDECAR_BYTES = 16 * 1024 * 1024
#: Most digits of a JSON integer: float32 reaches 3.4e38 (39 digits); longer ones are refused before conversion.
MAX_INT_DIGITS = 40
FLOAT32_MAX = float(np.finfo(np.float32).max)
INT64_RANGE = (-(2**63), 2**63)
#: ONNX input/output element types a policy may have: float32 (Box) or int64 (Discrete).
TENSOR_TYPES = ("tensor(float)", "tensor(int64)")


class ServeError(ValueError):
    """A malformed observation line (reported to the client, serving continues)."""


class Policy:
    """An ONNX policy plus the names from its sidecar.

    :param model_path: ONNX file with input ``(batch, obs_dim)`` float32 (or ``(batch,)`` int64).
    :param meta_path: sidecar JSON; default ``policy.json`` next to the model, if it exists.
    :raises FileNotFoundError, ValueError: the model or sidecar cannot be loaded (a one-line message naming the
        file and what is accepted).
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
            raise ValueError(f"invalid ONNX model {path}: {_first_line(exc)}") from None
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        #: ``(n_layers, hidden)`` of a recurrent graph's state (each of h and c), None for a stateless one
        self.state_shape = _state_shape(path, inputs, outputs)
        if self.state_shape is not None:
            inputs = inputs[:1]
        if len(inputs) != 1 or not outputs or inputs[0].type not in TENSOR_TYPES or outputs[0].type not in TENSOR_TYPES:
            raise ValueError(f"invalid policy model {path}: expected one float32 or int64 input and a float32 or int64 "
                             f"output (as python -m sbagents.export writes), got inputs "
                             f"{[(i.name, i.type) for i in inputs]}, outputs {[(o.name, o.type) for o in outputs]}")
        inp, out = inputs[0], outputs[0]
        self.input_name = inp.name
        self.discrete_obs = inp.type == "tensor(int64)"
        shape, out_shape = list(inp.shape[1:]), list(out.shape[1:])
        if not all(isinstance(d, int) and d > 0 for d in shape + out_shape):
            raise ValueError(f"invalid policy model {path}: the observation and action shapes must be static, got "
                             f"input {inp.shape} and output {out.shape}")
        if self.discrete_obs and shape:
            raise ValueError(f"invalid policy model {path}: an int64 (Discrete) input takes one index per row, got "
                             f"shape {inp.shape}")
        self.obs_dim = 1 if self.discrete_obs else int(np.prod(shape)) if shape else 1
        self.obs_shape = tuple(int(d) for d in shape)
        #: numbers in a recurrent request's or reply's ``state`` (0 for a stateless policy)
        self.state_size = 2 * self.state_shape[0] * self.state_shape[1] if self.state_shape is not None else 0
        #: longest observation line or body accepted for this policy (:func:`request_limit`)
        self.max_request_bytes = request_limit(self.obs_dim + self.state_size)
        self.discrete_action = out.type == "tensor(int64)"
        self.act_dim = 1 if self.discrete_action else int(np.prod(out_shape)) if out_shape else 1
        meta_file = Path(meta_path) if meta_path is not None else path.parent / "policy.json"
        meta = self._load_meta(meta_file, required=meta_path is not None)
        try:
            self.obs_names = _names(meta, "obs_names", self.obs_dim, "obs")
            self.action_names = _names(meta, "action_names", self.act_dim, "action")
            #: ``[low, high)`` of a Discrete observation (the sidecar's ``observation_space``; else int64's range)
            self.index_range = _index_range(meta) if self.discrete_obs else INT64_RANGE
        except ValueError as exc:
            raise ValueError(f"invalid sidecar {meta_file}: {exc}") from None

    @staticmethod
    def _load_meta(meta_file: Path, required: bool) -> dict[str, Any]:
        """The sidecar's JSON object (``{}`` when it is not there and not ``required``)."""
        if not meta_file.is_file():
            if required:
                raise FileNotFoundError(f"sidecar not found: {meta_file}")
            return {}
        what = f"invalid sidecar {meta_file}"
        if meta_file.stat().st_size > MAX_SIDECAR_BYTES:
            raise ValueError(f"{what}: {meta_file.stat().st_size} bytes; a policy.json is at most "
                             f"{MAX_SIDECAR_BYTES} bytes")
        try:
            meta = json.loads(meta_file.read_bytes().decode("utf-8"))
        except UnicodeDecodeError:
            raise ValueError(f"{what}: not UTF-8 text (expected the JSON object python -m sbagents.export "
                             "writes)") from None
        except (json.JSONDecodeError, RecursionError, ValueError) as exc:  # ValueError: an integer too long to read
            raise ValueError(f"{what}: not JSON ({_first_line(exc)})") from None
        if not isinstance(meta, dict):
            raise ValueError(f"{what}: a JSON {type(meta).__name__} where an object with obs_names and action_names "
                             "is expected")
        missing = [key for key in ("obs_names", "action_names") if key not in meta]
        if missing:
            raise ValueError(f"{what}: no {' or '.join(missing)} (lists of names, as python -m sbagents.export "
                             "writes)")
        return meta

    @property
    def recurrent(self) -> bool:
        """Whether the policy's state travels in requests and replies (``{"obs": ..., "state": ...}``)."""
        return self.state_shape is not None

    def parse(self, data: str | bytes) -> list[float]:
        """One observation line or body -> ``obs_dim`` finite numbers.

        :raises ServeError: anything but one observation (the message says what was wrong and what is accepted);
            nothing else is raised, whatever ``data`` holds.
        """
        if self.recurrent:
            raise ServeError('this policy is recurrent: send {"obs": <observation>, "state": <the previous '
                             'reply\'s state, or null at an episode start>}')
        return self._observation(_loads(data, self.max_request_bytes))

    def parse_step(self, data: str | bytes) -> tuple[list[float], list[float] | None]:
        """One request of a recurrent policy -> ``(observation, state)`` (state None: an episode starts); for a
        stateless policy the request is the observation and the state None.

        :raises ServeError: anything else (what was wrong and what is accepted).
        """
        value = _loads(data, self.max_request_bytes)
        if not self.recurrent:
            return self._observation(value), None
        if not isinstance(value, dict) or "obs" not in value or set(value) - {"obs", "state"}:
            keys = _clip_list(list(value)) if isinstance(value, dict) else _kind(value) if not isinstance(
                value, list) else "a list"
            raise ServeError(f'this policy is recurrent: send {{"obs": <observation>, "state": <the previous reply\'s '
                             f'state, or null at an episode start>}}, got {keys}')
        state = value.get("state")
        if state is not None:
            if not isinstance(state, list) or len(state) != self.state_size:
                size = f"{len(state)} values" if isinstance(state, list) else _kind(state)
                raise ServeError(f"state must be the {self.state_size} numbers of the previous reply (or null at "
                                 f"an episode start), got {size}")
            for v in state:
                if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or abs(
                        v) > FLOAT32_MAX:
                    raise ServeError(f"state holds {_show(v)}; it holds finite float32 numbers")
            state = [float(v) for v in state]
        return self._observation(value["obs"]), state

    def _observation(self, value: Any) -> list[float]:
        """A decoded JSON observation -> ``obs_dim`` finite numbers (:class:`ServeError` otherwise)."""
        if isinstance(value, dict):
            keys = set(value)
            unknown = sorted(keys - set(self.obs_names))
            missing = [k for k in self.obs_names if k not in keys]
            if unknown or missing:
                named = (("unknown", unknown), ("missing", missing))
                problems = [f"{what} keys {_clip_list(keys)}" for what, keys in named if keys]
                raise ServeError(f"{', '.join(problems)}; expected {list(self.obs_names)}")
            value = [value[k] for k in self.obs_names]
        elif self.discrete_obs and not isinstance(value, list):
            value = [value]
        if not isinstance(value, list):
            raise ServeError(f"observation must be a JSON list or object, got {_kind(value)}")
        if len(value) != self.obs_dim:
            raise ServeError(f"expected {self.obs_dim} values, got {len(value)}")
        for v in value:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ServeError(f"not a finite number: {_show(v)}")
            if self.discrete_obs:
                low, high = self.index_range
                if float(v) != int(v) or not low <= int(v) < high:
                    raise ServeError(f"a Discrete observation is an integer in [{low}, {high}), got {_show(v)}")
            elif abs(v) > FLOAT32_MAX:
                raise ServeError(f"{_show(v)} is outside the float32 range (+-{FLOAT32_MAX:.4g})")
        return [float(v) for v in value]

    def act(self, obs: Sequence[float]) -> list[float] | int:
        """Action for one observation: a list of floats (Box) or an int (Discrete); a recurrent policy acts as at
        an episode start (use :meth:`step` to carry its state).

        :raises ServeError: the policy gave a non-finite action (a JSON reply cannot carry it).
        """
        return self.step(obs, None)[0]

    def step(self, obs: Sequence[float], state: Sequence[float] | None) -> tuple[list[float] | int, list[float]]:
        """Action and next state (``[]`` for a stateless policy) for one observation; ``state`` None: an episode
        starts (zeros).

        :raises ServeError: the policy gave a non-finite action or state (a JSON reply cannot carry it).
        """
        x: np.ndarray
        if self.discrete_obs:
            x = np.asarray([int(obs[0])], dtype=np.int64)
        else:
            x = np.asarray(obs, dtype=np.float32).reshape((1, *self.obs_shape))
        feed = {self.input_name: x}
        if self.state_shape is not None:
            layers, hidden = self.state_shape
            flat = np.zeros(self.state_size, np.float32) if state is None else np.asarray(state, np.float32)
            h, c = flat.reshape((2, layers, 1, hidden))
            feed.update({"state_h": h, "state_c": c,
                         "episode_start": np.asarray([1.0 if state is None else 0.0], np.float32)})
        action, *next_state = self.session.run(None, feed)
        new_state = [float(v) for v in np.concatenate([np.asarray(t).reshape(-1) for t in next_state])] \
            if next_state else []
        if not all(math.isfinite(v) for v in new_state):
            raise ServeError("the policy gave a non-finite state for this observation")
        return self._action(action), new_state

    def _action(self, action: Any) -> list[float] | int:
        if self.discrete_action:
            return int(np.asarray(action).reshape(-1)[0])
        values = [float(a) for a in np.asarray(action).reshape(-1)]
        if not all(math.isfinite(a) for a in values):
            raise ServeError(f"the policy gave a non-finite action {values} for this observation")
        return values


def _state_shape(path: Path, inputs: Sequence[Any], outputs: Sequence[Any]) -> tuple[int, int] | None:
    """``(n_layers, hidden)`` of a recurrent policy graph (inputs ``obs, state_h, state_c, episode_start``, outputs
    ``action, state_h_out, state_c_out``), None for any other graph (checked as a stateless one)."""
    names = [i.name for i in inputs]
    if names[1:] != ["state_h", "state_c", "episode_start"]:
        return None
    h, c, start = inputs[1:]
    layers, hidden = h.shape[0], h.shape[2] if len(h.shape) == 3 else None
    if (len(outputs) != 3 or h.shape != c.shape or not isinstance(layers, int) or not isinstance(hidden, int)
            or layers < 1 or hidden < 1 or layers * hidden > 1 << 16 or any(
                t.type != "tensor(float)" for t in (h, c, start, *outputs[1:]))):
        raise ValueError(f"invalid policy model {path}: a recurrent policy has float32 state inputs state_h and "
                         "state_c (n_layers, batch, hidden), episode_start (batch,), and the action and the next "
                         "state as its three outputs (as python -m sbagents.export writes)")
    return layers, hidden


def request_limit(obs_dim: int) -> int:
    """The longest observation line or body accepted for a policy of ``obs_dim`` values, in bytes:
    :data:`MAX_REQUEST_BYTES`, or :data:`REQUEST_BYTES_PER_VALUE` a value when that is more (an Atari stack of 4
    84x84 frames, 28,224 values: 903,168 bytes)."""
    return max(MAX_REQUEST_BYTES, REQUEST_BYTES_PER_VALUE * obs_dim)


def _loads(data: str | bytes, limit: int = MAX_REQUEST_BYTES) -> Any:
    """``data`` as JSON, with the limits a server needs (size up to ``limit`` bytes, UTF-8, integer length,
    nesting); :class:`ServeError` for anything else."""
    if len(data) > limit:
        raise ServeError(f"observation of more than {limit} bytes; one observation is at most that")
    if isinstance(data, bytes):
        try:
            data = data.decode("utf-8")
        except UnicodeDecodeError:
            raise ServeError("not UTF-8 text; send one JSON observation") from None
    if not data.strip():
        raise ServeError("empty observation; send one JSON observation (a list of numbers or an object keyed by "
                         "obs_names)")
    try:
        return _DECODER.decode(data)
    except json.JSONDecodeError as exc:
        raise ServeError(f"bad JSON: {exc.msg} (at character {exc.pos})") from None
    except RecursionError:
        raise ServeError("bad JSON: nested too deeply; an observation is a flat list or object") from None


def _parse_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_INT_DIGITS:
        raise ServeError(f"a {digits}-digit integer is outside the float32 range (+-{FLOAT32_MAX:.4g})")
    return int(text)


def _refuse_constant(name: str) -> float:
    raise ServeError(f"not a finite number: {name} (JSON numbers only)")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object whose keys are all different (else which value counts would be a guess)."""
    seen: set[str] = set()
    for key, _ in pairs:
        if key in seen:
            raise ServeError(f"key {_show(key)} is given twice; give each observation name once")
        seen.add(key)
    return dict(pairs)


#: JSON with the hooks above, made once (``json.loads`` with hooks builds a decoder per call)
_DECODER = json.JSONDecoder(parse_int=_parse_int, parse_constant=_refuse_constant, object_pairs_hook=_unique_keys)


def _kind(value: Any) -> str:
    return {str: "a string", type(None): "null", bool: "a boolean"}.get(type(value), "a number")


def _show(value: Any, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters (a reply never echoes a whole hostile request)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _clip_list(items: list[str], shown: int = 5) -> str:
    head = ", ".join(_show(k) for k in items[:shown])
    return f"[{head}{f', ... ({len(items) - shown} more)' if len(items) > shown else ''}]"


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def _names(meta: dict[str, Any], key: str, size: int, prefix: str) -> tuple[str, ...]:
    """The sidecar's ``key`` (``size`` distinct strings), or ``<prefix>_<i>`` without a sidecar."""
    if not meta:
        return tuple(f"{prefix}_{i}" for i in range(size))
    names = meta[key]
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names) or len(set(names)) < len(names):
        raise ValueError(f"{key} must be a list of distinct non-empty strings, got {_show(names, 80)}")
    if len(names) != size:
        what = "observation" if prefix == "obs" else prefix
        raise ValueError(f"{key} has {len(names)} names; the model has {size} {what} values")
    return tuple(names)


def _index_range(meta: dict[str, Any]) -> tuple[int, int]:
    """``[start, start + n)`` of the sidecar's Discrete ``observation_space``; int64's range when it has none."""
    space = meta.get("observation_space")
    if not isinstance(space, dict) or space.get("type") != "discrete":
        return INT64_RANGE
    n, start = space.get("n"), space.get("start", 0)
    if not isinstance(n, int) or not isinstance(start, int) or isinstance(n, bool) or isinstance(start, bool) or n < 1:
        raise ValueError(f"observation_space n and start must be integers (n >= 1), got {_show(space, 80)}")
    return start, start + n


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


def decide(policy: Policy, data: str | bytes | None, log: DecisionLog) -> tuple[bool, str]:
    """One observation (JSON text or UTF-8 bytes) -> ``(ok, reply JSON)``: the action, or ``{"error": reason}``.

    ``None`` stands for a line that was too long to read. Nothing in ``data`` makes this raise: what cannot be
    decided on (malformed input, or a failure of the model on it) is an error reply. Served decisions are appended
    to ``log``.
    """
    if data is None:
        return False, error_reply(f"line of more than {policy.max_request_bytes} bytes; one observation is at most "
                                  "that")
    try:
        obs, state = policy.parse_step(data)
    except ServeError as exc:
        return False, error_reply(str(exc))
    try:
        action, next_state = policy.step(obs, state)
    except ServeError as exc:
        return False, error_reply(str(exc))
    except Exception as exc:  # onnxruntime's own exception types: the model failed on this input
        return False, error_reply(f"the policy could not decide on this observation: {_first_line(exc)}")
    log.write(obs, action)
    if policy.recurrent:
        return True, json.dumps({"action": action, "state": next_state}, allow_nan=False)
    return True, json.dumps(action, allow_nan=False)


def error_reply(reason: str) -> str:
    """``{"error": reason}`` as one line of JSON."""
    return json.dumps({"error": reason})


def read_lines(stream: BinaryIO, limit: int = MAX_REQUEST_BYTES) -> Iterator[bytes | None]:
    """The lines of ``stream`` (bytes, without the ``\\n``); ``None`` for a line over ``limit`` bytes, which is read
    past in chunks without being kept."""
    while line := stream.readline(limit + 1):
        if len(line) <= limit or line.endswith(b"\n"):
            yield line.removesuffix(b"\n")
            continue
        while (rest := stream.readline(limit)) and not rest.endswith(b"\n"):
            pass
        yield None


def serve(
    policy: Policy, lines: BinaryIO, out: TextIO, csv_path: str | Path | None = None
) -> tuple[int, int]:
    """Answer every line of ``lines`` (binary, e.g. ``sys.stdin.buffer``) with one line on ``out`` until it ends.

    :return: ``(n_served, n_errors)``.
    """
    served = errors = 0
    with DecisionLog(policy, csv_path) as log:
        for line in read_lines(lines, policy.max_request_bytes):
            ok, reply = decide(policy, line, log)
            out.write(reply + "\n")
            out.flush()
            served += ok
            errors += not ok
    return served, errors
