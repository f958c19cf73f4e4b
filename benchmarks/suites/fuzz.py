"""Fuzzing the files of a run dir: seeded mutations of model zips, ``.npz`` files, configs and monitor CSVs.

Two tiny seed runs are trained once (DDPG on SmartHome with VecNormalize statistics, a checkpoint, a best model,
``evaluations.npz`` and a replay buffer; PPO on GridWorld). Each case copies one run into a folder of its own, mutates
one file with ``random.Random("fuzz:SEED:CASE")`` and runs the command that reads it:

- **model** (``<env>.zip``, ``best_model.zip``, a checkpoint): byte mutations, or the members of the zip mutated and
  zipped again: the ``data`` JSON (values replaced by random JSON: huge numbers, deep nesting, long strings; entries
  deleted or added; ``:serialized:`` payloads replaced by mutated pickles), ``policy.pth`` (its ``data.pkl`` pickle,
  its tensor storages), members dropped, renamed or doubled; ``python -m sbagents.evaluate -n 1``;
- **vecnormalize**, **replay-buffer**, **evaluations** (``.npz``): the ``.npy`` headers of members (shape, dtype,
  header length, version), their data, the zip around them, or arrays replaced by others (dtypes, shapes, NaN, the
  JSON settings inside); ``evaluate``, ``train -i`` (which resumes the replay buffer) and ``plot``;
- **config** (``config.yml``, ``args.yml``): keys set to random YAML values, import paths, tags such as
  ``!!python/object/apply``, anchors and aliases that expand exponentially, deep nesting, bytes; ``evaluate`` or
  ``plot``;
- **monitor** (``N.monitor.csv``): the JSON header line, the column line, fields (``nan``, ``inf``, huge numbers,
  quotes), rows repeated, long lines, bytes; ``python -m sbagents.plot``.

A case's command runs in a process of its own, forked (``os.fork``) from a worker that has imported what the command
imports (a new interpreter costs seconds of imports here; a fork, milliseconds), and runs as ``python -m`` would
(``runpy``). Its peak resident memory is ``wait4``'s ``ru_maxrss`` plus, per command, how much more a new
interpreter's peak was than a forked process's on the unmutated files (measured once, ~110 MiB for ``evaluate``), so
the limit applies to what ``python -m sbagents.evaluate`` would reach. The workers import the code once: a tree
edited during a run is seen by the next run. Allowed outcomes: **ok** (exit 0) and **refused** (exit 2 with exactly
one line on stderr). Failures: **signal** (killed by a signal: a crash), **traceback**, **not-one-line**
(exit 2 with several lines), **bad-exit** (another exit code), **memory** (more than :data:`MEMORY_LIMIT_MIB` MiB
resident, or a ``MemoryError``), **timeout**, **outside-write** (a file written, removed or renamed outside the case's
folder: seen by an audit hook in the process, and by comparing the sandbox outside the case before and after; sbagents'
compiled-code cache, ``SBAGENTS_CACHE_DIR``, is the one folder outside it a case may write) and **code-exec** (the
process ran a command: ``os.system``, ``subprocess``, ``exec*``; but ``uname``, which ``platform.processor()`` runs).
Zip **bombs** (members that unpack to 256-900 MiB of zeros) are one mutation among others (``--no-bombs``: none).

    python -m benchmarks run fuzz [--cases 600] [--seed 0] [--timeout 120] [--no-bombs] [--kinds model,config]
    python -m benchmarks run fuzz --smoke      # one case per file kind, no bombs: a check that it runs
    python -m benchmarks run fuzz --seed S --case I --keep DIR     # one case again, its folder kept in DIR

The results (``benchmarks/results/fuzz.json``, also saved after every case: ``--progress``) hold the cases and
outcomes per file kind, and each failure with its seed and case number; section ``fuzz`` of ``BENCHMARKS.md``.
``tests/test_fuzz_files.py`` runs a bounded number of cases with the same harness.
"""

from __future__ import annotations

import argparse
import ast
import base64
import contextlib
import importlib
import io
import json
import os
import pickletools
import random
import resource
import runpy
import shlex
import shutil
import signal
import struct
import subprocess
import sys
import sysconfig
import tempfile
import time
import traceback
import warnings
import zipfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import RESULTS_DIR, save_results

SECTION = "fuzz"
REPO = Path(__file__).resolve().parents[2]

#: The file kinds a case mutates, in the order cases cycle through them.
KINDS: tuple[str, ...] = ("model", "vecnormalize", "replay-buffer", "evaluations", "config", "monitor")
#: The outcomes a case may have; every one but the first two is a failure.
OUTCOMES: tuple[str, ...] = ("ok", "refused", "signal", "traceback", "not-one-line", "bad-exit", "memory", "timeout",
                             "outside-write", "code-exec")
ALLOWED: tuple[str, ...] = OUTCOMES[:2]
#: Most resident memory a case's process may reach (MiB), and the address space it may map (a guard for the machine).
MEMORY_LIMIT_MIB = 500
ADDRESS_LIMIT = 4 << 30

DDPG_ENV, DDPG_STEM = "sbagents/SmartHome-v0", "sbagents_SmartHome-v0"
PPO_ENV, PPO_STEM = "sbagents/GridWorld-v0", "sbagents_GridWorld-v0"
DDPG_RUN = f"ddpg/{DDPG_STEM}_1"
PPO_RUN = f"ppo/{PPO_STEM}_1"
STEPS = 300
#: How the seed runs are trained (``python -m sbagents.train ...``, in the folder ``seeds/<name>``).
SEED_RUNS: dict[str, list[str]] = {
    "ddpg": ["--algo", "ddpg", "--env", DDPG_ENV, "-n", str(STEPS), "-f", "logs", "--seed", "0", "--eval-freq", "150",
             "--eval-episodes", "1", "--final-eval-episodes", "0", "--save-freq", str(STEPS), "--save-replay-buffer",
             "--verbose", "0", "-params", "learning_starts:50", "buffer_size:1000"],
    "ppo": ["--algo", "ppo", "--env", PPO_ENV, "-n", "256", "-f", "logs", "--seed", "0", "--eval-freq", "-1",
            "--final-eval-episodes", "0", "--verbose", "0"],
}
#: The commands' modules: each has a worker that imports it (and, once warmed up, whatever running it imports).
GROUPS: tuple[str, ...] = ("sbagents.evaluate", "sbagents.train", "sbagents.plot")
#: Commands run by sbagents itself that a case may run: ``platform.processor()`` (SB3's system info) runs ``uname``.
ALLOWED_COMMANDS: tuple[str, ...] = ("uname",)


# --- mutations ------------------------------------------------------------------------------------------------------
class Raw(str):
    """JSON text put verbatim into a document by :func:`dump_json` (deep nesting, numbers beyond Python's limits)."""


def dump_json(value: Any) -> str:
    """``value`` as JSON text, :class:`Raw` pieces as they are (``json.dumps`` with NaN and Infinity otherwise)."""
    if isinstance(value, Raw):
        return str(value)
    if isinstance(value, dict):
        return "{" + ",".join(json.dumps(str(k)) + ":" + dump_json(v) for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ",".join(dump_json(v) for v in value) + "]"
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    return json.dumps(value)


#: Integers at the edges of the widths file formats use.
INTERESTING_INTS: tuple[int, ...] = (0, 1, -1, 2, 7, 255, 256, -129, 65535, 65536, 2**31 - 1, -(2**31), 2**32,
                                     2**53 + 1, 2**63 - 1, -(2**63), 2**64, 10**30, 2**1000)
INTERESTING_FLOATS: tuple[float, ...] = (0.0, -0.0, 1e308, -1e308, 5e-324, float("nan"), float("inf"), float("-inf"))
#: Strings a file might hold where a name, a class or a path is expected ({OUTSIDE}: a folder outside the case).
INTERESTING_STRINGS: tuple[str, ...] = (
    "", "x", "Box", "Discrete", "MultiBinary", "float32", "float64", "O", "object", "<f8", "|V2147483647",
    "<U1000000000", "MlpPolicy", "CnnPolicy", "MultiInputPolicy", "os.system", "builtins.eval", "builtins.exec",
    "subprocess.Popen", "stable_baselines3.common.save_util.load_from_pkl", "torch.nn.modules.activation.ReLU",
    "torch.nn.ReLU", "sbagents.envs", "numpy.ndarray", "../../../{OUTSIDE}/x", "{OUTSIDE}/marker", "\x00", "\u00e9",
    "\U0001f642", "%s%n%x", "a" * 300, "\n\n", "auto", "cpu", "cuda:7", "null", "True", "1e999",
)
#: Module and name pairs a mutated pickle may reference.
GLOBALS: tuple[tuple[str, str], ...] = (
    ("os", "system"), ("builtins", "eval"), ("builtins", "getattr"), ("builtins", "bytearray"), ("posix", "system"),
    ("subprocess", "Popen"), ("numpy", "dtype"), ("numpy", "ndarray"), ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "_reconstruct"), ("numpy._core.numeric", "_frombuffer"), ("collections", "OrderedDict"),
    ("collections", "deque"), ("gymnasium.spaces.box", "Box"), ("gymnasium.spaces.discrete", "Discrete"),
    ("torch._utils", "_rebuild_tensor_v2"), ("torch", "FloatStorage"), ("copyreg", "_reconstructor"),
    ("stable_baselines3.common.utils", "FloatSchedule"), ("stable_baselines3.td3.policies", "TD3Policy"),
)
INT_OPS = {"INT", "LONG", "BININT", "BININT1", "BININT2", "LONG1", "LONG4"}
STR_OPS = {"SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8", "UNICODE", "SHORT_BINSTRING", "BINSTRING", "STRING"}
BYTES_OPS = {"SHORT_BINBYTES", "BINBYTES", "BINBYTES8", "BYTEARRAY8"}
#: Single pickle opcodes (with arguments) to insert: structure, memo and call opcodes.
PICKLE_OPS: tuple[bytes, ...] = (b"R", b"b", b".", b"(", b"0", b"1", b"2", b"e", b"u", b"s", b"a", b"t", b")", b"]",
                                 b"}", b"N", b"\x94", b"\x93", b"\x81", b"\x92", b"h\x00", b"h\xff",
                                 b"j\xff\xff\xff\x7f", b"\x85", b"\x86", b"\x87", b"\x88", b"\x89", b"\x95" + bytes(8),
                                 b"\x80\x05", b"\x80\xff", b"\x97", b"\x98", b"\x96" + struct.pack("<Q", 2**62))
#: Keys a config may hold (the seed runs' own are added).
CONFIG_KEYS: tuple[str, ...] = (
    "policy", "n_timesteps", "normalize", "env_wrapper", "callback", "policy_kwargs", "frame_stack", "n_envs",
    "env_kwargs", "learning_rate", "buffer_size", "batch_size", "gamma", "noise_type", "noise_std", "learning_starts",
    "train_freq", "gradient_steps", "tau", "vec_env_wrapper", "deterministic_eval", "self_play", "max_episode_steps",
    "algo", "env", "seed", "log_folder", "trained_agent", "vec_env", "device", "eval_episodes", "eval_freq",
    "gym_packages", "n_steps", "ent_coef", "clip_range", "normalize_advantage", "use_sde", "replay_buffer_class",
    "replay_buffer_kwargs", "optimize_memory_usage", "policy_delay", "target_policy_noise",
)
#: YAML texts for a value: tags (some would run code under an unsafe loader), big numbers, odd scalars.
YAML_VALUES: tuple[str, ...] = (
    '!!python/object/apply:os.system ["touch {OUTSIDE}/yaml-apply"]', "!!python/name:os.system",
    "!!python/module:os", '!!python/object/new:subprocess.Popen [["touch", "{OUTSIDE}/yaml-new"]]',
    "!!python/tuple [1, 2]", "!!binary aGVsbG8=", "!!set {a: null, b: null}",
    "!!timestamp 2001-12-14t21:59:43.10-05:00",
    "!!omap [{a: 1}, {b: 2}]", "!!float .nan", "!!float .inf", "!!int 0x7fffffffffffffffffffffff", "!!str 1",
    "!custom x", "!!map {}", "!!seq []", "!!null ''", "1" + "0" * 5000, "1e999", "-.inf", "0o777", "0b1010", "~",
    "? [complex, key]", "{[1, 2]: x}", "&a [*a]", "*undefined", "'unclosed", "[" * 200 + "]" * 200,
    "{a: {b: {c: {d: {e: {f: {g: {h: 1}}}}}}}}", '"\\x00\\ud800"', "|\n  block\n  scalar", "yes", "off",
)
NPY_DESCRS: tuple[Any, ...] = ("|O", "<f8", ">f8", "<f4", "<f2", "<i8", "|u1", "|b1", "<c16", "<U2147483647", "|V0",
                               "|V4294967295", "|S0", "<M8[ns]", "<m8", [("a", "<f8"), ("b", "|O")], "garbage", 7,
                               None, "<f16", "float32")


class Mutator:
    """Seeded mutations of one file's bytes; :attr:`log` lists what was done (for the report).

    :param rng: the case's random generator.
    :param outside: a folder outside the case (payloads that try to write name it).
    :param bombs: whether zip members that unpack to hundreds of MiB may be made.
    """

    def __init__(self, rng: random.Random, outside: Path, bombs: bool = True) -> None:
        self.rng = rng
        self.outside = str(outside)
        self.bombs = bombs
        self.log: list[str] = []

    def note(self, text: str) -> None:
        self.log.append(text[:160])

    def text(self, value: str) -> str:
        return value.replace("{OUTSIDE}", self.outside)

    def mutate(self, kind: str, data: bytes) -> bytes:
        """One file of ``kind`` mutated (1 to 3 mutations; most aware of the file's structure)."""
        if kind == "model":
            return self.model_zip(data)
        if kind in ("vecnormalize", "replay-buffer", "evaluations"):
            return self.npz(data)
        if kind == "config":
            return self.yaml_file(data)
        if kind == "monitor":
            return self.monitor(data)
        raise ValueError(f"unknown file kind {kind!r}")

    # --- bytes ---
    def bytes_(self, data: bytes, where: str = "") -> bytes:
        """A byte-level mutation: bits flipped, bytes set, chunks inserted, deleted or repeated, truncation."""
        rng = self.rng
        op = rng.choices(["flip", "bytes", "insert", "delete", "duplicate", "truncate", "int", "empty", "random"],
                         weights=[4, 3, 3, 3, 2, 3, 3, 1, 1])[0]
        buf = bytearray(data)
        n = len(buf)
        if op == "flip" and n:
            for _ in range(rng.randint(1, 8)):
                buf[rng.randrange(n)] ^= 1 << rng.randrange(8)
        elif op == "bytes" and n:
            for _ in range(rng.randint(1, 8)):
                buf[rng.randrange(n)] = rng.choice((0x00, 0xFF, 0x7F, 0x80, 0x20, 0x0A, 0x22, 0x5C))
        elif op == "insert":
            at = rng.randint(0, n)
            buf[at:at] = rng.randbytes(rng.choice((1, 4, 16, 256, 4096)))
        elif op == "delete" and n:
            at = rng.randrange(n)
            del buf[at : at + rng.randint(1, min(n - at, 4096))]
        elif op == "duplicate" and n:
            at = rng.randrange(n)
            chunk = bytes(buf[at : at + rng.randint(1, 4096)]) * rng.choice((1, 2, 16))
            to = rng.randint(0, n)
            buf[to:to] = chunk
        elif op == "truncate":
            buf = buf[: rng.randint(0, max(n - 1, 0))]
        elif op == "int" and n >= 8:
            width = rng.choice((1, 2, 4, 8))
            value = rng.choice(INTERESTING_INTS) % (1 << (8 * width))
            at = rng.randrange(n - width + 1)
            buf[at : at + width] = value.to_bytes(width, rng.choice(("little", "big")))
        elif op == "empty":
            buf = bytearray()
        else:
            op = "random"
            buf = bytearray(rng.randbytes(rng.randint(1, 4096)))
        self.note(f"{where}bytes:{op}")
        return bytes(buf)

    # --- zips ---
    def zip_members(self, data: bytes, member: Callable[[str, bytes], bytes], weights: Callable[[str], float],
                    bomb: Callable[[str], tuple[str, bytes, bytes]] | None, where: str) -> bytes:
        """The zip ``data`` with its members mutated (by ``member``), dropped, renamed, doubled or added, zipped again;
        ``bomb`` (name -> member name, prefix, filler) makes a member that unpacks to hundreds of MiB."""
        rng = self.rng
        members = read_zip(data)
        if members is None:
            return self.bytes_(data, where)
        ops = ["member"] * 6 + ["drop", "rename", "double", "add"] + (["bomb"] if self.bombs and bomb else [])
        out: list[tuple[str, bytes | tuple[int, bytes, bytes]]] = list(members)
        for _ in range(rng.choice((1, 1, 1, 2))):
            op = rng.choice(ops)
            names = [name for name, _ in out]
            if not names:
                op = "add"
            if op == "member":
                index = rng.choices(range(len(out)), weights=[weights(n) for n in names])[0]
                name, content = out[index]
                if isinstance(content, bytes):
                    out[index] = (name, member(name, content))
            elif op == "drop":
                index = rng.randrange(len(out))
                self.note(f"{where}drop {out[index][0]}")
                del out[index]
            elif op == "rename":
                index = rng.randrange(len(out))
                new = rng.choice(("", "/", "../x", "data", "../../" + out[index][0], out[index][0] + "\x00", "ö" * 300))
                self.note(f"{where}rename {out[index][0]} -> {new!r}")
                out[index] = (new, out[index][1])
            elif op == "double":
                index = rng.randrange(len(out))
                name, content = out[index]
                replacement = (self.bytes_(content, f"{where}{name} doubled: ") if isinstance(content, bytes)
                               else content)
                self.note(f"{where}double {name}")
                out.insert(rng.randint(0, len(out)), (name, replacement))
            elif op == "add":
                name = rng.choice(("extra", "data", "policy.pth", "__settings__.npy", "x.npy", "../escape"))
                self.note(f"{where}add {name}")
                out.append((name, rng.randbytes(rng.randint(0, 512))))
            elif bomb is not None:
                index = rng.randrange(len(out))
                target, prefix, filler = bomb(out[index][0])
                size = rng.choice((256, 600, 900)) << 20
                self.note(f"{where}bomb {target}: {size >> 20} MiB")
                out[index] = (target, (size, prefix, filler))
        compression = zipfile.ZIP_DEFLATED if rng.random() < 0.2 else zipfile.ZIP_STORED
        result = write_zip(out, compression)
        if rng.random() < 0.1:
            result = self.bytes_(result, f"{where}zip ")
        return result

    def model_zip(self, data: bytes) -> bytes:
        """An SB3 model zip: its ``data`` JSON, its ``.pth`` files (zips of a pickle and tensor storages), the rest."""

        def member(name: str, content: bytes) -> bytes:
            if name == "data":
                return self.data_json(content)
            if name.endswith(".pth") and self.rng.random() < 0.75:
                return self.pth(name, content)
            return self.bytes_(content, f"{name}: ")

        def weights(name: str) -> float:
            return {"data": 10.0, "policy.pth": 5.0}.get(name, 1.0)

        def bomb(name: str) -> tuple[str, bytes, bytes]:
            if name == "data":
                return name, b"", b" "  # JSON whitespace, then nothing: a 900 MiB blank document
            return name, b"", b"\0"

        if self.rng.random() < 0.1:
            return self.bytes_(data)
        return self.zip_members(data, member, weights, bomb, "")

    def data_json(self, content: bytes) -> bytes:
        """The ``data`` JSON of a model: values replaced, keys deleted or added, ``:serialized:`` pickles mutated."""
        rng = self.rng
        try:
            obj = json.loads(content)
        except (ValueError, RecursionError):
            return self.bytes_(content, "data: ")
        if not isinstance(obj, dict):
            return self.bytes_(content, "data: ")
        serialized = [k for k, v in obj.items() if isinstance(v, dict) and ":serialized:" in v]
        for _ in range(rng.randint(1, 3)):
            op = rng.choices(["set", "delete", "add", "pickle", "base64", "swap", "type"],
                             weights=[5, 2, 2, 5, 1, 1, 1])[0]
            if op == "pickle" and serialized:
                key = rng.choice(serialized)
                entry = obj.get(key)
                if isinstance(entry, dict) and isinstance(entry.get(":serialized:"), str):
                    try:
                        payload = base64.b64decode(entry[":serialized:"])
                    except (ValueError, RecursionError):
                        payload = b""
                    entry[":serialized:"] = base64.b64encode(self.pickle(payload, f"data[{key!r}]: ")).decode()
                    continue
            if op == "base64" and serialized:
                key = rng.choice(serialized)
                garbage = rng.choice(("", "====", "not base64!", "gAWV" * 1000,
                                      base64.b64encode(rng.randbytes(64)).decode()))
                obj[key] = {**obj[key], ":serialized:": garbage} if isinstance(obj[key], dict) else garbage
                self.note(f"data[{key!r}] serialized -> {garbage[:20]!r}")
                continue
            if op == "swap" and len(obj) > 1:
                a, b = rng.sample(list(obj), 2)
                obj[a], obj[b] = obj[b], obj[a]
                self.note(f"data: swap {a!r} {b!r}")
                continue
            if op == "type" and serialized:
                key = rng.choice(serialized)
                if isinstance(obj[key], dict):
                    obj[key][":type:"] = rng.choice(INTERESTING_STRINGS)
                    self.note(f"data[{key!r}] :type: changed")
                    continue
            if op == "delete":
                path = pick_path(obj, rng)
                if path:
                    delete_path(obj, path)
                    self.note(f"data: delete {path}")
                    continue
            if op == "add":
                key = rng.choice((*obj, "extra", "__proto__", "")) + rng.choice(("", "_x"))
                obj[key] = self.random_json()
                self.note(f"data: add {key!r}")
                continue
            path = pick_path(obj, rng)
            value = self.random_json()
            if path:
                set_path(obj, path, value)
            self.note(f"data: set {path} = {dump_json(value)[:40]}")
        text = dump_json(obj).encode("utf-8", "surrogatepass")
        return self.bytes_(text, "data text: ") if rng.random() < 0.1 else text

    def random_json(self, depth: int = 0) -> Any:
        """A random JSON value: edge numbers, names, containers, or raw text (deep nesting, numbers beyond limits)."""
        rng = self.rng
        kind = rng.choices(["none", "bool", "int", "float", "str", "list", "dict", "raw"],
                           weights=[1, 1, 4, 2, 3, 2 if depth < 3 else 0, 2 if depth < 3 else 0, 2])[0]
        if kind == "none":
            return None
        if kind == "bool":
            return rng.random() < 0.5
        if kind == "int":
            return rng.choice(INTERESTING_INTS)
        if kind == "float":
            return rng.choice(INTERESTING_FLOATS)
        if kind == "str":
            return self.text(rng.choice(INTERESTING_STRINGS))
        if kind == "list":
            return [self.random_json(depth + 1) for _ in range(rng.randint(0, 4))]
        if kind == "dict":
            keys = ("type", "shape", "dtype", "low", "high", "n", ":type:", ":serialized:", "net_arch", "x")
            return {rng.choice(keys): self.random_json(depth + 1) for _ in range(rng.randint(0, 4))}
        n = rng.choice((64, 1000, 100_000))
        return Raw(rng.choice((
            "[" * n + "]" * n, '{"a":' * n + "0" + "}" * n, "1" + "0" * rng.choice((400, 5000, 100_000)),
            '"' + "A" * rng.choice((1 << 12, 1 << 20, 1 << 24)) + '"', '"\\ud800\\udfff\\u0000"', "1e999", "-1e999",
            "123456789e123456789", "-0", "[" + ",".join(["1e308"] * n) + "]",
        )))

    # --- pickles ---
    def pickle(self, payload: bytes, where: str = "") -> bytes:
        """A pickle mutated opcode by opcode: numbers, strings, bytes and globals replaced, opcodes deleted, doubled,
        swapped or inserted, the stream cut; ``FRAME`` opcodes mostly dropped so the changes count."""
        rng = self.rng
        try:
            ops = list(pickletools.genops(payload))
        except Exception:  # not a pickle (an earlier mutation): bytes only
            return self.bytes_(payload, where)
        pieces: list[tuple[str, bytes]] = []
        for i, (info, _arg, pos) in enumerate(ops):
            end = ops[i + 1][2] if i + 1 < len(ops) else len(payload)
            pieces.append((info.name, payload[pos or 0 : end]))
        if rng.random() < 0.8:
            pieces = [p for p in pieces if p[0] != "FRAME"]
        done: list[str] = []
        for _ in range(rng.randint(1, 3)):
            op: str = rng.choices(["int", "str", "bytes", "global", "delete", "double", "swap", "insert", "cut"],
                             weights=[4, 4, 2, 2, 2, 1, 1, 2, 1])[0]
            targets = {"int": INT_OPS, "str": STR_OPS, "bytes": BYTES_OPS, "global": {"GLOBAL"}}.get(op)
            if targets is not None:
                indices = [i for i, (name, _) in enumerate(pieces) if name in targets]
                if not indices:
                    op = "insert"
                else:
                    i = rng.choice(indices)
                    pieces[i] = (pieces[i][0], self.pickle_value(op))
            if op == "delete" and len(pieces) > 1:
                del pieces[rng.randrange(len(pieces))]
            elif op == "double" and pieces:
                i = rng.randrange(len(pieces))
                pieces.insert(i, pieces[i])
            elif op == "swap" and len(pieces) > 1:
                i, j = rng.sample(range(len(pieces)), 2)
                pieces[i], pieces[j] = pieces[j], pieces[i]
            elif op == "insert":
                pieces.insert(rng.randint(0, len(pieces)), ("X", rng.choice(PICKLE_OPS)))
            elif op == "cut":
                pieces = pieces[: rng.randint(0, len(pieces))]
            done.append(op)
        self.note(f"{where}pickle {'+'.join(done)}")
        return b"".join(p for _, p in pieces)

    def pickle_value(self, what: str) -> bytes:
        rng = self.rng
        if what == "int":
            return pickle_int(rng.choice(INTERESTING_INTS))
        if what == "str":
            pool = [*INTERESTING_STRINGS, *(m for m, _ in GLOBALS), *(n for _, n in GLOBALS)]
            return pickle_str(self.text(rng.choice(pool)))
        if what == "bytes":
            return pickle_bytes(rng.choice((b"", b"\0", rng.randbytes(7), rng.randbytes(300), bytes(1 << 16))))
        module, name = rng.choice(GLOBALS)
        return b"c" + module.encode() + b"\n" + name.encode() + b"\n"

    def pth(self, where: str, content: bytes) -> bytes:
        """A ``torch.save`` file (a zip): its ``data.pkl`` pickle, tensor storages, version and byte-order files."""

        def member(name: str, data: bytes) -> bytes:
            if name.endswith("data.pkl"):
                return self.pickle(data, f"{where}/{name}: ")
            if "/data/" in name and self.rng.random() < 0.5:
                cut = self.rng.choice((0, len(data) // 2, max(len(data) - 1, 0), len(data) + 8))
                self.note(f"{where}/{name}: storage {len(data)} -> {cut} bytes")
                return (data + bytes(8))[:cut]
            if name.endswith(("version", "byteorder")) and self.rng.random() < 0.5:
                value = self.rng.choice((b"big", b"99", b"-1", b"", b"3\n", b"little\0"))
                self.note(f"{where}/{name} = {value!r}")
                return value
            return self.bytes_(data, f"{where}/{name}: ")

        def weights(name: str) -> float:
            return 6.0 if name.endswith("data.pkl") else 3.0 if "/data/" in name else 1.0

        return self.zip_members(content, member, weights, None, f"{where}: ")

    # --- npy and npz ---
    def npz(self, data: bytes) -> bytes:
        """An ``.npz``: arrays replaced by others (or its JSON settings mutated), else ``.npy`` headers and data, and
        the zip around them."""
        if self.rng.random() < 0.4:
            result = self.npz_arrays(data)
            if result is not None:
                return result

        def member(name: str, content: bytes) -> bytes:
            return self.npy(name, content) if self.rng.random() < 0.8 else self.bytes_(content, f"{name}: ")

        def bomb(name: str) -> tuple[str, bytes, bytes]:
            return name, b"", b""  # prefix filled in by write_zip from the size: a valid float64 array of zeros

        return self.zip_members(data, member, lambda name: 1.0, bomb, "")

    def npy(self, name: str, content: bytes) -> bytes:
        """One ``.npy`` member: its header's shape, dtype or order, the header's text, length or version, its data."""
        rng = self.rng
        parsed = parse_npy(content)
        if parsed is None:
            return self.bytes_(content, f"{name}: ")
        version, header, body = parsed
        op = rng.choice(("shape", "shape", "descr", "descr", "fortran", "text", "length", "version", "body"))
        try:
            fields = ast.literal_eval(header)
        except (ValueError, SyntaxError):
            fields = None
        if not isinstance(fields, dict):
            op = "text"
        if op == "shape":
            old = tuple(fields.get("shape", ()))  # type: ignore[union-attr]
            fields["shape"] = rng.choice((  # type: ignore[index]
                (), (0,), (-1,), (2**62,), (2**31, 2**31), (1,) * 40, (1.5,), ("a",), old[::-1], old + (1,),
                (old[0] * 2,) + old[1:] if old else (3,), (old[0] + 1,) + old[1:] if old else (2,), None, [2, 2],
                (10**6, 10**6),
            ))
        elif op == "descr":
            fields["descr"] = rng.choice(NPY_DESCRS)  # type: ignore[index]
        elif op == "fortran":
            fields["fortran_order"] = rng.choice((True, 1, "x", None))  # type: ignore[index]
        if op in ("shape", "descr", "fortran"):
            self.note(f"{name}: {op} -> {fields.get(op if op != 'fortran' else 'fortran_order')!r}"[:160])  # type: ignore[union-attr]
            return build_npy(repr(fields), body, version)
        if op == "text":
            text = rng.choice(("{}", "[]", "", "{'descr': '<f8', 'fortran_order': False, 'shape': (1,), 'x': 1}",
                               "{'descr': '<f8', 'shape': (3,)", "__import__('os').system('true')", "{" * 500,
                               "{'descr': '<f8', 'fortran_order': False, 'shape': (" + "9" * 5000 + ",)}",
                               header + " " * 70000))
            self.note(f"{name}: header text -> {text[:40]!r}")
            return build_npy(text, body, version)
        if op == "length":
            value = rng.choice((0, 1, 9, 65535, len(header) + 64, len(header) - 16))
            self.note(f"{name}: header length -> {value}")
            width = 2 if version[0] == 1 else 4
            return content[:8] + (value % (1 << 8 * width)).to_bytes(width, "little") + content[8 + width :]
        if op == "version":
            new = rng.choice(((2, 0), (3, 0), (9, 9), (0, 0), (1, 1)))
            self.note(f"{name}: version -> {new}")
            return content[:6] + bytes(new) + content[8:]
        cut = rng.choice((0, len(body) // 2, max(len(body) - 1, 0), len(body) + 8, len(body) * 3))
        self.note(f"{name}: data {len(body)} -> {cut} bytes")
        return content[: len(content) - len(body)] + (body * 4 + bytes(8))[:cut]

    def npz_arrays(self, data: bytes) -> bytes | None:
        """An ``.npz`` whose arrays were replaced, deleted, added or renamed (``np.savez``; object arrays pickled),
        or whose JSON strings (settings) were mutated."""
        import numpy as np

        rng = self.rng
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as loaded:
                arrays = {name: loaded[name] for name in loaded.files}
        except Exception:
            return None
        if not arrays:
            return None
        for _ in range(rng.randint(1, 2)):
            name = rng.choice(sorted(arrays))
            value = arrays[name]
            op = rng.choice(("array", "array", "json", "delete", "add", "rename"))
            if op == "json" and value.dtype.kind == "U" and value.ndim == 0:
                try:
                    obj = json.loads(str(value))
                except (ValueError, RecursionError):
                    obj = None
                if isinstance(obj, dict) and obj:
                    path = pick_path(obj, rng)
                    new = self.random_json()
                    if rng.random() < 0.2:
                        delete_path(obj, path)
                    else:
                        set_path(obj, path, new)
                    arrays[name] = np.asarray(dump_json(obj))
                    self.note(f"{name}: JSON {path} -> {dump_json(new)[:40]}")
                    continue
            if op == "delete":
                del arrays[name]
                self.note(f"delete {name}")
            elif op == "add":
                new_name = rng.choice(("extra", "array/x", "obs_rms/mean", "json/infos", "__settings__", "a" * 200))
                arrays[new_name] = self.random_array(value)
                self.note(f"add {new_name}")
            elif op == "rename":
                new_name = rng.choice(("", "x", "../x", name + "/", name.upper(), "array/observations"))
                arrays[new_name] = arrays.pop(name)
                self.note(f"rename {name} -> {new_name!r}")
            else:
                arrays[name] = self.random_array(value)
                self.note(f"{name}: {value.dtype}{value.shape} -> {arrays[name].dtype}{arrays[name].shape}")
        out = io.BytesIO()
        np.savez(out, **arrays)
        return write_zip(read_zip(out.getvalue()) or [], zipfile.ZIP_STORED)  # np.savez stamps the time

    def random_array(self, like: Any) -> Any:
        import numpy as np

        rng = self.rng
        shape = tuple(like.shape)
        shape = rng.choice(((), (0,), shape, shape + (2,), ((shape[0] + 1,) + shape[1:]) if shape else (2,), (7, 3),
                            (1,) * 6, shape[::-1]))
        if int(np.prod(shape)) > 100_000:
            shape = (7, 3)
        dtype = rng.choice(("float64", "float32", "float16", "int64", "uint8", "bool", "complex128", "U8", "S4",
                            "datetime64[s]", "object", like.dtype))
        if dtype == "object":
            return np.array([1, "a", None, [2]], dtype=object)
        fill = rng.choice((0, 1, -1, 1e300, float("nan"), float("inf"), -(2**62)))
        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                return np.full(shape, fill).astype(dtype)
        except (ValueError, TypeError, OverflowError):
            return np.zeros(shape, dtype=dtype)

    # --- YAML ---
    def yaml_file(self, data: bytes) -> bytes:
        """A config: keys set to random values, deleted or added, then maybe text injected (tags, anchors that expand
        exponentially, deep nesting, odd scalars), or bytes mutated, or the whole document replaced."""
        import yaml

        rng = self.rng
        try:
            obj = yaml.safe_load(data)
        except yaml.YAMLError:
            obj = None
        if not isinstance(obj, dict) or rng.random() < 0.1:
            return self.bytes_(data, "yaml: ")
        if rng.random() < 0.05:
            whole = rng.choice(("", "null", "42", "- a\n- list\n", "a: b: c", "\ta: 1", "%YAML 9.9\n---\na: 1",
                                "--- 1\n--- 2\n", "\ufeffa: 1"))
            self.note(f"yaml: whole document -> {whole!r}")
            return whole.encode()
        keys = sorted({*map(str, obj), *CONFIG_KEYS})
        for _ in range(rng.randint(0, 2)):
            op = rng.choice(("set", "set", "delete", "nested"))
            if op == "delete" and obj:
                key = rng.choice(sorted(obj, key=str))
                del obj[key]
                self.note(f"yaml: delete {key}")
            elif op == "nested" and any(isinstance(v, dict) for v in obj.values()):
                key = rng.choice(sorted(k for k, v in obj.items() if isinstance(v, dict)))
                sub = obj[key]
                inner = rng.choice(sorted({*map(str, sub), "net_arch", "activation_fn", "x", "norm_obs", "clip_obs"}))
                sub[inner] = self.random_yaml()
                self.note(f"yaml: set {key}.{inner}")
            else:
                key = rng.choice(keys)
                obj[key] = self.random_yaml()
                self.note(f"yaml: set {key} = {str(obj[key])[:40]}")
        text = yaml.safe_dump(obj, sort_keys=False, allow_unicode=True)
        if rng.random() < 0.6:
            key = rng.choice(keys)
            inject = rng.choice(("value", "value", "bomb", "deep", "merge", "long"))
            if inject == "value":
                text += f"{key}: {self.text(rng.choice(YAML_VALUES))}\n"
            elif inject == "bomb":
                levels = rng.choice((6, 9, 12))
                text += "x0: &x0 [a, a, a, a, a, a, a, a, a]\n" + "".join(
                    f"x{i}: &x{i} [{', '.join([f'*x{i - 1}'] * 9)}]\n" for i in range(1, levels))
                text += f"{key}: *x{levels - 1}\n"
            elif inject == "deep":
                n = rng.choice((100, 1000, 20_000))
                text += f"{key}: " + rng.choice(("[" * n + "]" * n, "{a: " * n + "1" + "}" * n)) + "\n"
            elif inject == "merge":
                text += f"base: &base {{{key}: 1, policy: x}}\n{key}:\n  <<: *base\n  <<: [*base, *base]\n"
            else:
                text += f"{key}: {'x' * rng.choice((1 << 16, 1 << 22))}\n"
            self.note(f"yaml: {key}: {inject}")
        result = text.encode("utf-8", "surrogatepass")
        return self.bytes_(result, "yaml text: ") if rng.random() < 0.15 else result

    def random_yaml(self, depth: int = 0) -> Any:
        rng = self.rng
        kind = rng.choice(("none", "bool", "int", "float", "str", "str", "list" if depth < 3 else "str",
                           "dict" if depth < 3 else "int", "import"))
        if kind == "none":
            return None
        if kind == "bool":
            return rng.random() < 0.5
        if kind == "int":
            return rng.choice(INTERESTING_INTS)
        if kind == "float":
            return rng.choice(INTERESTING_FLOATS)
        if kind == "str":
            return self.text(rng.choice(INTERESTING_STRINGS))
        if kind == "list":
            return [self.random_yaml(depth + 1) for _ in range(rng.randint(0, 4))]
        if kind == "dict":
            return {self.text(rng.choice(INTERESTING_STRINGS + CONFIG_KEYS)): self.random_yaml(depth + 1)
                    for _ in range(rng.randint(0, 3))}
        module, name = rng.choice(GLOBALS)
        target = f"{module}.{name}"
        return rng.choice((target, [target], [{target: {"command": self.text("touch {OUTSIDE}/cfg")}}],
                           {target: {"args": ["touch", self.text("{OUTSIDE}/cfg")]}}))

    # --- monitor CSV ---
    def monitor(self, data: bytes) -> bytes:
        """A ``Monitor`` CSV: the JSON header line, the column line, fields, rows repeated or added, line endings."""
        rng = self.rng
        lines = data.split(b"\n")
        for _ in range(rng.randint(1, 3)):
            op = rng.choices(["header", "columns", "field", "delete", "repeat", "long", "junk", "ending", "bytes"],
                             weights=[2, 2, 5, 1, 2, 1, 1, 1, 2])[0]
            rows = [i for i, line in enumerate(lines) if line and not line.startswith(b"#")][1:]
            if op == "header" and lines and lines[0].startswith(b"#"):
                try:
                    head = json.loads(lines[0][1:])
                except (ValueError, RecursionError):
                    head = {}
                path = pick_path(head, rng) if isinstance(head, dict) and rng.random() < 0.7 else []
                value = self.random_json()
                if path:
                    set_path(head, path, value)
                else:
                    head = value
                lines[0] = rng.choice((b"#", b"", b"# ")) + dump_json(head).encode("utf-8", "surrogatepass")
                self.note(f"monitor header {path} = {dump_json(value)[:40]}")
            elif op == "columns":
                index = next((i for i, line in enumerate(lines) if line and not line.startswith(b"#")), 0)
                lines[index] = rng.choice((b"", b"r,l", b"l,r,t", b"r,l,t,r", b"r,l,t,extra", b"x,y,z", b"r;l;t",
                                           b"\xff\xfe", b'"r","l","t"', b"r,l,t," * 1000))
                self.note(f"monitor columns -> {lines[index][:30]!r}")
            elif op == "field" and rows:
                index = rng.choice(rows)
                fields = lines[index].split(b",")
                at = rng.randrange(len(fields) + 1)
                value = rng.choice((b"nan", b"inf", b"-inf", b"1e308", b"-1e999", b"", b"x", b"0x10", b"1" * 5000,
                                    b"-0", b"True", b'"a,b"', b"\x00", b"9" * 20, b"-5", b"1.5", b"-1", b"1e18"))
                if at == len(fields):
                    fields.append(value)
                else:
                    fields[at] = value
                lines[index] = b",".join(fields)
                self.note(f"monitor field {at} of row {index} -> {value[:20]!r}")
            elif op == "delete" and rows:
                del lines[rng.choice(rows)]
                self.note("monitor delete row")
            elif op == "repeat" and rows:
                index = rng.choice(rows)
                times = rng.choice((10, 1000, 100_000))
                lines[index:index] = [lines[index]] * times
                self.note(f"monitor repeat a row {times} times")
            elif op == "long":
                size = rng.choice((1 << 16, 1 << 20, 1 << 24))
                lines.insert(rng.randint(1, len(lines)), rng.choice((b"1", b"x", b",")) * size)
                self.note(f"monitor line of {size} bytes")
            elif op == "junk":
                lines.insert(rng.randint(0, len(lines)), rng.randbytes(rng.randint(1, 64)))
                self.note("monitor junk line")
            elif op == "ending":
                ending = rng.choice((b"\r\n", b"\r", b"\n\n", b"\x00\n"))
                self.note(f"monitor line ends {ending!r}")
                return ending.join(lines)[: rng.choice((None, -1))]
            else:
                return self.bytes_(b"\n".join(lines), "monitor: ")
        return b"\n".join(lines)


def pick_path(obj: Any, rng: random.Random, max_depth: int = 4) -> list[Any]:
    """A random path of keys (and list indices) into ``obj``, at least one step when ``obj`` is not empty."""
    path: list[Any] = []
    current = obj
    while isinstance(current, dict | list) and current and len(path) < max_depth:
        key = rng.choice(list(current)) if isinstance(current, dict) else rng.randrange(len(current))
        path.append(key)
        current = current[key]
        if rng.random() < 0.45:
            break
    return path


def set_path(obj: Any, path: Sequence[Any], value: Any) -> None:
    for key in path[:-1]:
        obj = obj[key]
    obj[path[-1]] = value


def delete_path(obj: Any, path: Sequence[Any]) -> None:
    if not path:
        return
    for key in path[:-1]:
        obj = obj[key]
    del obj[path[-1]]


def pickle_int(value: int) -> bytes:
    """The pickle opcode that pushes ``value``."""
    if 0 <= value < 256:
        return b"K" + bytes([value])
    if 0 <= value < 65536:
        return b"M" + struct.pack("<H", value)
    if -(2**31) <= value < 2**31:
        return b"J" + struct.pack("<i", value)
    raw = value.to_bytes((value.bit_length() + 8) // 8, "little", signed=True)
    return (b"\x8a" + bytes([len(raw)]) if len(raw) < 256 else b"\x8b" + struct.pack("<i", len(raw))) + raw


def pickle_str(value: str) -> bytes:
    raw = value.encode("utf-8", "surrogatepass")
    return (b"\x8c" + bytes([len(raw)]) if len(raw) < 256 else b"X" + struct.pack("<I", len(raw))) + raw


def pickle_bytes(value: bytes) -> bytes:
    return (b"C" + bytes([len(value)]) if len(value) < 256 else b"B" + struct.pack("<I", len(value))) + value


def parse_npy(content: bytes) -> tuple[tuple[int, int], str, bytes] | None:
    """The version, header text and data of an ``.npy`` file; ``None`` when it is not one."""
    if not content.startswith(b"\x93NUMPY") or len(content) < 10:
        return None
    version = (content[6], content[7])
    width = 2 if version[0] == 1 else 4
    length = int.from_bytes(content[8 : 8 + width], "little")
    start = 8 + width
    header = content[start : start + length]
    if len(header) != length:
        return None
    return version, header.decode("latin1"), content[start + length :]


def build_npy(header: str, body: bytes, version: tuple[int, int] = (1, 0)) -> bytes:
    """An ``.npy`` file from a header text (padded as numpy pads it) and data."""
    width = 2 if version[0] == 1 else 4
    raw = header.encode("latin1", "replace")
    pad = (-(8 + width + len(raw) + 1)) % 64
    raw += b" " * pad + b"\n"
    if width == 2 and len(raw) >= 1 << 16:
        version, width = (2, 0), 4
    return b"\x93NUMPY" + bytes(version) + len(raw).to_bytes(width, "little") + raw + body


def read_zip(data: bytes) -> list[tuple[str, bytes]] | None:
    """The members of a zip, in order; ``None`` when ``data`` is not a readable zip."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            return [(info.filename, archive.read(info)) for info in archive.infolist()]
    except Exception:
        return None


#: The time stamp of every zip member this harness writes (the same bytes for the same seed).
ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def write_zip(members: Sequence[tuple[str, bytes | tuple[int, bytes, bytes]]], compression: int) -> bytes:
    """A zip of ``members``; a member given as ``(size, prefix, filler)`` is ``prefix`` then ``filler`` up to ``size``
    bytes, always deflated (a bomb: small on disk); an empty ``prefix`` and ``filler`` make a float64 ``.npy``."""
    out = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # duplicate names are the point
        with zipfile.ZipFile(out, "w", compression) as archive:
            for name, content in members:
                if isinstance(content, bytes):
                    archive.writestr(zipfile.ZipInfo(name, ZIP_TIME), content, compress_type=compression)
                    continue
                size, prefix, filler = content
                if not prefix and not filler:
                    prefix = build_npy(repr({"descr": "<f8", "fortran_order": False, "shape": (size // 8,)}), b"")
                    filler = b"\0"
                info = zipfile.ZipInfo(name, ZIP_TIME)
                info.compress_type = zipfile.ZIP_DEFLATED
                with archive.open(info, "w", force_zip64=True) as fh:
                    fh.write(prefix)
                    block = filler * (1 << 20)
                    for _ in range(size >> 20):
                        fh.write(block)
    return out.getvalue()


# --- cases ----------------------------------------------------------------------------------------------------------
@dataclass
class Case:
    """One mutated file and the command that reads it.

    :param seed: the run's ``--seed``.
    :param index: the case's number (its mutations: ``random.Random(f"fuzz:{seed}:{index}")``).
    :param kind: one of :data:`KINDS`.
    :param file: the mutated file, relative to the case's folder.
    :param argv: the command's arguments after ``python`` (``-m module ...``), run in the case's folder.
    :param mutations: what was done to the file (empty: the file as trained).
    """

    seed: int
    index: int
    kind: str
    file: str
    argv: list[str]
    mutations: list[str] = field(default_factory=list)

    @property
    def group(self) -> str:
        return self.argv[1]

    def command(self) -> str:
        return "python " + shlex.join(self.argv)


@dataclass
class Outcome:
    """What a case's process did: :data:`OUTCOMES` name, exit code (negative: killed by that signal), peak resident
    memory as a new interpreter's (the forked process's, ``forked_mib``, plus the clean command's difference between
    the two), seconds, the end of stderr, and what broke the rules (paths written outside, commands run)."""

    outcome: str
    returncode: int
    maxrss_mib: float
    seconds: float
    stderr_tail: str
    detail: str = ""
    forked_mib: float = 0.0

    @property
    def failed(self) -> bool:
        return self.outcome not in ALLOWED


def evaluate_argv(algo: str, env: str, *extra: str) -> list[str]:
    return ["-m", "sbagents.evaluate", "--algo", algo, "--env", env, "-f", "logs", "-n", "1", "--seed", "0",
            "--json", *extra]


PLOT_ARGV = ["-m", "sbagents.plot", "-f", "logs", "-o", "curves.png"]
RESUME_ARGV = ["-m", "sbagents.train", "--algo", "ddpg", "--env", DDPG_ENV, "-f", "more", "-n", "20", "-i",
               f"logs/{DDPG_RUN}/{DDPG_STEM}.zip", "-params", "buffer_size:1000", "learning_starts:0", "--eval-freq",
               "-1", "--save-freq", "-1", "--final-eval-episodes", "0", "--verbose", "0", "--seed", "0"]
#: The command of each file kind (the first of a kind is the one :func:`clean_cases` checks).
CONSUMERS: dict[str, str] = {
    "model": "evaluate -n 1", "vecnormalize": "evaluate -n 1", "replay-buffer": "train -i (resumes the buffer)",
    "evaluations": "plot", "config": "evaluate -n 1 or plot", "monitor": "plot",
}


def choose_target(kind: str, rng: random.Random) -> tuple[str, str, list[str]]:
    """The seed run (``ddpg``/``ppo``), the file (relative to the copied ``logs``) and the command of a case."""
    if kind == "model":
        if rng.random() < 0.3:
            return "ppo", f"{PPO_RUN}/{PPO_STEM}.zip", evaluate_argv("ppo", PPO_ENV)
        which = rng.choice(("final", "final", "best", "checkpoint"))
        if which == "best":
            return "ddpg", f"{DDPG_RUN}/best_model.zip", evaluate_argv("ddpg", DDPG_ENV, "--load-best")
        if which == "checkpoint":
            return ("ddpg", f"{DDPG_RUN}/rl_model_{STEPS}_steps.zip",
                    evaluate_argv("ddpg", DDPG_ENV, "--load-checkpoint", str(STEPS)))
        return "ddpg", f"{DDPG_RUN}/{DDPG_STEM}.zip", evaluate_argv("ddpg", DDPG_ENV)
    if kind == "vecnormalize":
        if rng.random() < 0.25:
            return ("ddpg", f"{DDPG_RUN}/rl_model_vecnormalize_{STEPS}_steps.npz",
                    evaluate_argv("ddpg", DDPG_ENV, "--load-checkpoint", str(STEPS)))
        return "ddpg", f"{DDPG_RUN}/vecnormalize.npz", evaluate_argv("ddpg", DDPG_ENV)
    if kind == "replay-buffer":
        return "ddpg", f"{DDPG_RUN}/replay_buffer.npz", list(RESUME_ARGV)
    if kind == "evaluations":
        return "ddpg", f"{DDPG_RUN}/evaluations.npz", list(PLOT_ARGV)
    if kind == "config":
        run, stem, algo, env = rng.choice(((DDPG_RUN, DDPG_STEM, "ddpg", DDPG_ENV), (DDPG_RUN, DDPG_STEM, "ddpg",
                                           DDPG_ENV), (PPO_RUN, PPO_STEM, "ppo", PPO_ENV)))
        name = rng.choice(("config.yml", "args.yml"))
        argv = list(PLOT_ARGV) if rng.random() < 0.25 else evaluate_argv(algo, env)
        return algo, f"{run}/{stem}/{name}", argv
    if kind == "monitor":
        if rng.random() < 0.5:
            return "ddpg", f"{DDPG_RUN}/0.monitor.csv", list(PLOT_ARGV)
        return "ppo", f"{PPO_RUN}/{rng.randrange(8)}.monitor.csv", list(PLOT_ARGV)
    raise ValueError(f"unknown file kind {kind!r}; known: {', '.join(KINDS)}")


def clean_cases() -> list[tuple[str, str, list[str]]]:
    """Each distinct command once on unmutated files (every one must exit 0): (kind, seed run, argv)."""
    return [("model", "ddpg", evaluate_argv("ddpg", DDPG_ENV)), ("model", "ppo", evaluate_argv("ppo", PPO_ENV)),
            ("replay-buffer", "ddpg", list(RESUME_ARGV)), ("monitor", "ddpg", list(PLOT_ARGV))]


# --- the worker: a process that has imported the commands' modules and forks one process per case ---------------------
_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND
_PATH_EVENTS = {"os.remove", "os.rmdir", "os.mkdir", "os.truncate", "os.chmod", "os.chown", "os.utime", "os.link",
                "os.symlink", "os.mkfifo", "os.mknod", "shutil.rmtree", "shutil.copyfile", "shutil.copymode",
                "shutil.copystat", "shutil.chown", "shutil.move", "shutil.copytree", "shutil.make_archive"}
_EXEC_EVENTS = {"os.system", "subprocess.Popen", "os.exec", "os.posix_spawn", "os.spawn", "os.startfile",
                "pty.spawn", "ctypes.dlopen"}


def _guard(roots: Sequence[str], report_fd: int) -> Callable[[str, tuple[Any, ...]], None]:
    """An audit hook that writes one JSON line to ``report_fd`` per write, removal or rename outside ``roots`` and per
    command run (but :data:`ALLOWED_COMMANDS`)."""
    prefixes = tuple(root.rstrip(os.sep) + os.sep for root in roots)
    allowed = {os.devnull, "/dev/stdout", "/dev/stderr", "/dev/tty", *roots}

    def outside(path: Any) -> bool:
        if path is None or isinstance(path, int):
            return False
        try:
            full = os.path.abspath(os.fsdecode(path))
        except (TypeError, ValueError):
            return False
        if full in allowed or full.startswith(prefixes):
            return False
        real = os.path.realpath(full)
        return not (real in allowed or real.startswith(prefixes))

    def report(kind: str, what: Any) -> None:
        os.write(report_fd, (json.dumps([kind, repr(what)[:300]]) + "\n").encode())

    def hook(event: str, args: tuple[Any, ...]) -> None:
        if event == "open":
            path, mode, flags = (tuple(args) + (None, None, None))[:3]
            writing = (any(c in mode for c in "wax+") if isinstance(mode, str)
                       else isinstance(flags, int) and bool(flags & _WRITE_FLAGS))
            if writing and outside(path):
                report("write", path)
        elif event == "os.mkdir":
            if args and outside(args[0]) and not os.path.isdir(os.fsdecode(args[0])):  # makedirs(exist_ok) asks too
                report("write", args[0])
        elif event in _PATH_EVENTS:
            if args and outside(args[0]) or event in ("shutil.copyfile", "shutil.move", "os.link", "os.symlink") \
                    and len(args) > 1 and outside(args[1]):
                report("write", args[:2])
        elif event == "os.rename":
            if outside(args[0]) or outside(args[1]):
                report("write", args[:2])
        elif event in _EXEC_EVENTS:
            if event == "ctypes.dlopen":
                return  # libraries load lazily (torch, numpy); a path of the case's own would show as a write first
            command = args[1] if event == "subprocess.Popen" and len(args) > 1 else None
            if isinstance(command, list | tuple) and command and os.path.basename(str(command[0])) in ALLOWED_COMMANDS:
                return
            report("exec", (event, *args[:2]))

    return hook


def _child(request: dict[str, Any]) -> int:
    """In the forked process: run ``python ARGV`` as ``python`` would (``-m module`` or a script), output to files."""
    os.setpgid(0, 0)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    for fd, name in ((1, "stdout"), (2, "stderr")):
        os.dup2(os.open(request[name], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), fd)
    events = os.open(request["events"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    cwd = os.path.realpath(request["cwd"])
    os.chdir(cwd)
    tmp = os.path.join(cwd, "tmp")
    os.makedirs(tmp, exist_ok=True)
    os.environ["TMPDIR"] = tmp
    tempfile.tempdir = None
    if request.get("address_limit"):
        limit = int(request["address_limit"])
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    sys.addaudithook(_guard([cwd, *request.get("writable", [])], events))
    argv = list(request["argv"])
    code = 1
    try:
        if argv[0] == "-m":
            sys.argv = [argv[1], *argv[2:]]
            sys.modules.pop(argv[1], None)  # imported by the worker: run afresh as __main__, as ``python -m`` does
            runpy.run_module(argv[1], run_name="__main__", alter_sys=True)
        else:
            sys.argv = argv
            runpy.run_path(argv[0], run_name="__main__")
        code = 0
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            code = int(exc.code or 0)
        else:
            print(exc.code, file=sys.stderr)
            code = 1
    except BaseException:
        traceback.print_exc()
        code = 1
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    return code


def _fork_run(request: dict[str, Any]) -> dict[str, Any]:
    """Fork, run the request in the child, wait (``SIGKILL`` to its process group after ``timeout`` seconds)."""
    start = time.monotonic()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 1
        try:
            code = _child(request)
        finally:
            os._exit(code)
    deadline = start + float(request["timeout"])
    timed_out = False
    while True:
        done, status, usage = os.wait4(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            done, status, usage = os.wait4(pid, 0)
            timed_out = True
            break
        time.sleep(0.005)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pid, signal.SIGKILL)  # what the case's process left running in its group
    return {"returncode": os.waitstatus_to_exitcode(status), "maxrss_kib": usage.ru_maxrss,
            "seconds": time.monotonic() - start, "timed_out": timed_out}


def fresh_main() -> None:
    """``python -c ... OUT -m MODULE ARGS...``: run the module as ``python -m`` does, then write to OUT (JSON) the
    modules it imported and its peak resident memory (``VmHWM``: this process's since it started)."""
    out, module, args = sys.argv[1], sys.argv[3], sys.argv[4:]
    sys.argv = [module, *args]
    code = 0
    try:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        with open("/proc/self/status") as fh:
            hwm = [int(line.split()[1]) for line in fh if line.startswith("VmHWM:")]
        with open(out, "w") as fh:
            json.dump({"modules": sorted(m for m in sys.modules if m != "__main__"), "hwm_kib": hwm[0] if hwm else 0,
                       "returncode": code}, fh)
    sys.exit(code)


def _import_all(names: Sequence[str]) -> None:
    for name in names:
        if name not in sys.modules:
            with contextlib.suppress(Exception):
                importlib.import_module(name)


def worker_main(preload: Sequence[str]) -> None:
    """The worker (``python -c ... MODULE...``): import the modules, answer ``ready``, then for each request line on
    stdin (JSON) fork a case's process and answer its result line (JSON) on stdout; a request ``{"import": FILE}``
    imports the modules FILE lists (a warm-up run's), so a case's process starts where a fresh one would be after
    its imports (seconds here) and does the rest."""
    requests = os.fdopen(os.dup(0), "rb", buffering=0)  # unbuffered: a forked child must not inherit read-ahead
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
    os.dup2(2, 1)  # stray prints of imports go to the worker's log, not into the answers
    sys.stdin = open(os.devnull)  # noqa: SIM115 - kept open for the process's life
    _import_all(preload)
    answers.write("ready\n")
    while True:
        line = requests.readline()
        if not line:
            return
        request = json.loads(line)
        if "import" in request:
            for path in request["import"]:
                _import_all(json.loads(Path(path).read_text())["modules"])
            answers.write(json.dumps({"imported": len(sys.modules)}) + "\n")
        else:
            answers.write(json.dumps(_fork_run(request)) + "\n")


class Worker:
    """A worker process that has imported ``preload``, started in ``env``."""

    def __init__(self, preload: Sequence[str], env: dict[str, str], log: Path) -> None:
        code = "import sys; from benchmarks.suites.fuzz import worker_main; worker_main(sys.argv[1:])"
        self.log = log
        with log.open("ab") as err:
            self.proc = subprocess.Popen([sys.executable, "-c", code, *preload], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=err, cwd=REPO, env=env, text=True)
        self.ready = False

    def _line(self) -> str:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the fuzz worker exited; see {self.log}")
        return line

    def send(self, request: dict[str, Any]) -> None:
        """Send a request (answered by :meth:`receive`; several workers work at once in between)."""
        assert self.proc.stdin is not None
        if not self.ready:
            if self._line().strip() != "ready":
                raise RuntimeError(f"the fuzz worker did not start; see {self.log}")
            self.ready = True
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()

    def receive(self) -> dict[str, Any]:
        result: dict[str, Any] = json.loads(self._line())
        return result

    def run(self, request: dict[str, Any]) -> dict[str, Any]:
        self.send(request)
        return self.receive()

    def close(self) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(OSError):
                assert self.proc.stdin is not None
                self.proc.stdin.close()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


# --- classification -------------------------------------------------------------------------------------------------
def classify(returncode: int, stderr: str, maxrss_mib: float, timed_out: bool = False,
             events: Sequence[tuple[str, str]] = (), changed: Sequence[str] = ()) -> tuple[str, str]:
    """The outcome (one of :data:`OUTCOMES`) of a finished case and a detail line."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    if timed_out:
        return "timeout", ""
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except (ValueError, RecursionError):
            name = f"signal {-returncode}"
        return "signal", name
    execs = [what for kind, what in events if kind == "exec"]
    if execs:
        return "code-exec", "; ".join(execs[:3])
    writes = [what for kind, what in events if kind == "write"] + list(changed)
    if writes:
        return "outside-write", "; ".join(writes[:3])
    if maxrss_mib > MEMORY_LIMIT_MIB or "MemoryError" in stderr:
        return "memory", f"{maxrss_mib:.0f} MiB resident"
    if "Traceback (most recent call last)" in stderr:
        return "traceback", ""
    if returncode == 0:
        return "ok", ""
    if returncode == 2:
        return ("refused", "") if len(lines) == 1 else ("not-one-line", f"{len(lines)} lines")
    return "bad-exit", f"exit {returncode}"


def snapshot(root: Path, skip: Sequence[Path] = ()) -> dict[str, tuple[int, int]]:
    """Size and modification time of every file and folder under ``root`` but the folders ``skip``."""
    found: dict[str, tuple[int, int]] = {}
    skipped = set(skip)
    for folder, dirs, files in os.walk(root):
        here = Path(folder)
        dirs[:] = [d for d in dirs if here / d not in skipped]
        for name in files:
            with contextlib.suppress(OSError):
                stat = (here / name).lstat()
                found[str((here / name).relative_to(root))] = (stat.st_size, stat.st_mtime_ns)
        for name in dirs:
            found[str((here / name).relative_to(root)) + "/"] = (0, 0)  # a folder that appears or goes away
    return found


def changes(before: dict[str, tuple[int, int]], after: dict[str, tuple[int, int]]) -> list[str]:
    """The paths that appeared, went away or changed between two :func:`snapshot` s."""
    return sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))


# --- the fuzzer -----------------------------------------------------------------------------------------------------
class Fuzzer:
    """Seed runs, workers and a sandbox under ``folder``; :meth:`case` builds and runs one case.

    The sandbox: ``seeds/`` (the trained runs), ``cases/case-SEED-INDEX/`` (a case's folder: its copy of a run in
    ``logs``, where its command runs), ``home/`` (``HOME``), ``outside/`` (an empty folder the payloads name),
    ``cache/`` (``SBAGENTS_CACHE_DIR``: sbagents' compiled-code cache, the one place outside a case's folder a case
    may write), ``tmp/`` and ``workers/`` (the harness's own). Anything else written under the sandbox but outside
    the running case's folder is an outside write, like any write the audit hook sees outside the case's folder.

    :param folder: the sandbox (created).
    :param timeout: seconds a case may run.
    :param bombs: allow zip members that unpack to hundreds of MiB.
    :param keep: a folder to move failed cases' folders into (``None``: removed).
    :param keep_all: move every case's folder into ``keep``.
    """

    #: Sandbox folders of the harness, not compared before and after a case.
    OWN = ("tmp", "workers", "cache")

    def __init__(self, folder: Path, timeout: float = 120.0, bombs: bool = True, keep: Path | None = None,
                 keep_all: bool = False) -> None:
        self.folder = Path(folder).resolve()
        self.timeout = timeout
        self.bombs = bombs
        self.keep = keep
        self.keep_all = keep_all
        for sub in ("seeds", "cases", "home", "outside", *self.OWN):
            (self.folder / sub).mkdir(parents=True, exist_ok=True)
        self.env = {**os.environ, "HOME": str(self.folder / "home"), "TMPDIR": str(self.folder / "tmp"),
                    "MPLCONFIGDIR": str(self.folder / "home/.config/matplotlib"),
                    "XDG_CACHE_HOME": str(self.folder / "home/.cache"), "MPLBACKEND": "Agg",
                    "SBAGENTS_CACHE_DIR": str(self.folder / "cache"), "PYTHONUNBUFFERED": "1",
                    "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)}
        self.workers: dict[str, Worker] = {}
        #: Per module: how much more a new interpreter's peak memory was than a forked process's on the clean files.
        self.offset: dict[str, float] = {}
        #: The clean commands' cases and outcomes, and their peak memory in a new interpreter (:meth:`prepare`).
        self.clean: list[tuple[Case, Outcome, float]] = []

    def __enter__(self) -> Fuzzer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for worker in self.workers.values():
            worker.close()
        self.workers.clear()

    def worker(self, module: str) -> Worker:
        if module not in self.workers:
            self.workers[module] = Worker([module], self.env, self.folder / "workers" / f"{module}.log")
        return self.workers[module]

    def raw_run(self, argv: Sequence[str], cwd: Path, timeout: float | None = None, worker: str | None = None
                ) -> tuple[dict[str, Any], str, str, list[tuple[str, str]]]:
        """Run ``python -m MODULE ARGS`` (``argv``; or ``python SCRIPT ARGS`` through ``worker``, a module of
        :data:`GROUPS`) in ``cwd`` in a process forked by the module's worker: (the worker's answer, stdout, stderr,
        audit events)."""
        io_dir = Path(tempfile.mkdtemp(prefix="io-", dir=self.folder / "tmp"))
        request = {"argv": list(argv), "cwd": str(cwd), "timeout": timeout or self.timeout,
                   "stdout": str(io_dir / "stdout"), "stderr": str(io_dir / "stderr"), "events": str(io_dir / "events"),
                   "address_limit": ADDRESS_LIMIT, "writable": [str(self.folder / "cache")]}
        answer = self.worker(worker or argv[1]).run(request)

        def read(name: str) -> str:
            return (io_dir / name).read_text(errors="replace") if (io_dir / name).exists() else ""

        events: list[tuple[str, str]] = [(str(k), str(w)) for k, w in
                                         (json.loads(line) for line in read("events").splitlines() if line.strip())]
        out, err = read("stdout"), read("stderr")
        shutil.rmtree(io_dir, ignore_errors=True)
        return answer, out, err, events

    def fresh(self, jobs: Sequence[tuple[list[str], Path]]) -> list[dict[str, Any]]:
        """Run each ``python -m MODULE ARGS`` (``argv``) in its folder in a new interpreter, all at once (through
        :func:`fresh_main`): for each, the modules it imported, its peak memory, the file these are in (``path``)."""
        code = "from benchmarks.suites.fuzz import fresh_main; fresh_main()"
        started = []
        for argv, cwd in jobs:
            out = Path(tempfile.mkstemp(prefix="fresh-", suffix=".json", dir=self.folder / "tmp")[1])
            with out.with_suffix(".err").open("wb") as err:
                started.append((subprocess.Popen([sys.executable, "-c", code, str(out), *argv], cwd=cwd, env=self.env,
                                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err),
                                out, argv))
        for proc, _, _ in started:
            proc.wait()
        results = []
        for proc, out, argv in started:
            text = out.read_text() if out.exists() else ""
            if proc.returncode != 0 or not text:
                tail = out.with_suffix(".err").read_text(errors="replace")[-2000:]
                raise RuntimeError(f"`python {shlex.join(argv)}` failed (exit {proc.returncode}): {tail}")
            results.append({**json.loads(text), "path": str(out)})
        return results

    def prepare(self) -> None:
        """Train the seed runs (once: kept in ``seeds/``), run each clean command once in a new interpreter (its
        peak memory, and the modules it imported, which its worker then imports too), then in a forked process (its
        peak memory there: the difference is added to every case's). All before any case: what this writes (the
        compiled-code cache, matplotlib's font cache in ``HOME``) is no case's doing.

        :raises RuntimeError: a seed run failed to train, or a clean command failed.
        """
        for module in GROUPS:
            self.worker(module)  # they start while the seed runs train
        seeds = [(name, args) for name, args in SEED_RUNS.items()
                 if not (self.folder / "seeds" / name / "logs").is_dir()]
        for name, _ in seeds:
            (self.folder / "seeds" / name).mkdir(parents=True, exist_ok=True)
        trained = self.fresh([(["-m", "sbagents.train", *args], self.folder / "seeds" / name) for name, args in seeds])
        jobs = []
        for n, (_kind, run, argv) in enumerate(clean_cases()):
            folder = self.folder / "tmp" / f"warm-{n}"
            shutil.rmtree(folder, ignore_errors=True)
            shutil.copytree(self.folder / "seeds" / run / "logs", folder / "logs")
            jobs.append((argv, folder))
        warmed = self.fresh(jobs)
        imports: dict[str, list[str]] = {"sbagents.train": [r["path"] for r in trained]}
        for (argv, _), result in zip(jobs, warmed, strict=True):
            imports.setdefault(argv[1], []).append(result["path"])
        for module, paths in imports.items():
            self.worker(module).send({"import": paths})
        for module in imports:
            self.worker(module).receive()
        for _, folder in jobs:
            shutil.rmtree(folder, ignore_errors=True)
        self.clean = []
        for n, ((kind, run, argv), result) in enumerate(zip(clean_cases(), warmed, strict=True)):
            case, outcome = self.case(0, n, kind, clean=(run, argv))
            fresh = result["hwm_kib"] / 1024
            self.offset[argv[1]] = max(self.offset.get(argv[1], 0.0), fresh - outcome.forked_mib)
            self.clean.append((case, outcome, round(fresh, 1)))

    def case(self, seed: int, index: int, kind: str | None = None, clean: tuple[str, list[str]] | None = None
             ) -> tuple[Case, Outcome]:
        """Build case ``index`` of ``seed`` (its file of ``kind`` mutated; ``clean``: (seed run, argv) unmutated), run
        it, classify it; the case's folder is removed (moved into ``keep`` when it failed)."""
        kind = kind or KINDS[index % len(KINDS)]
        rng = random.Random(f"fuzz:{seed}:{index}")
        if clean is not None:
            run, file, argv = clean[0], "", list(clean[1])
        else:
            run, file, argv = choose_target(kind, rng)
        case_dir = self.folder / "cases" / (f"case-{seed}-{index}" if clean is None else f"clean-{index}")
        shutil.rmtree(case_dir, ignore_errors=True)
        shutil.copytree(self.folder / "seeds" / run / "logs", case_dir / "logs")
        case = Case(seed, index, kind, f"logs/{file}" if file else "", argv)
        if clean is None:
            path = case_dir / "logs" / file
            mutator = Mutator(rng, self.folder / "outside", self.bombs)
            path.write_bytes(mutator.mutate(kind, path.read_bytes()))
            case.mutations = mutator.log
        result = self.check(argv, case_dir)
        if (result.failed or self.keep_all) and self.keep is not None:
            target = self.keep / case_dir.name
            shutil.rmtree(target, ignore_errors=True)
            self.keep.mkdir(parents=True, exist_ok=True)
            shutil.move(str(case_dir), target)
            (target / "reproduce.txt").write_text(f"cd {target} && {case.command()}\n")
        else:
            shutil.rmtree(case_dir, ignore_errors=True)
        case.mutations = [self.relative(m) for m in case.mutations]
        return case, result

    def check(self, argv: Sequence[str], case_dir: Path, worker: str | None = None,
              timeout: float | None = None) -> Outcome:
        """Run ``argv`` in ``case_dir`` (see :meth:`raw_run`) and classify what it did (:func:`classify`), the
        sandbox outside ``case_dir`` compared before and after."""
        skip = [case_dir, *(self.folder / own for own in self.OWN)]
        before = snapshot(self.folder, skip)
        answer, _out, err, events = self.raw_run(argv, case_dir, timeout, worker)
        changed = [f"SANDBOX/{k}" for k in changes(before, snapshot(self.folder, skip))]
        forked = answer["maxrss_kib"] / 1024
        maxrss = forked + self.offset.get(worker or argv[1], 0.0)
        outcome, detail = classify(answer["returncode"], err, maxrss, answer["timed_out"], events, changed)
        tail = "\n".join(err.strip().splitlines()[-6:])[-1500:]
        return Outcome(outcome, answer["returncode"], round(maxrss, 1), round(answer["seconds"], 2),
                       self.relative(tail), self.relative(detail), round(forked, 1))

    def relative(self, text: str) -> str:
        """``text`` without this machine's paths: the sandbox becomes ``SANDBOX``, the repository ``REPO``, Python's
        folders ``SITE`` (site-packages), ``STDLIB`` and ``PREFIX``."""
        paths = sysconfig.get_paths()
        for path, name in ((str(self.folder), "SANDBOX"), (str(REPO), "REPO"), (paths["purelib"], "SITE"),
                           (paths["platlib"], "SITE"), (paths["stdlib"], "STDLIB"), (sys.prefix, "PREFIX")):
            text = text.replace(path, name)
        return text


@contextlib.contextmanager
def fuzzer(folder: Path | None = None, **kwargs: Any) -> Iterator[Fuzzer]:
    """A prepared :class:`Fuzzer` in ``folder`` (default: a temporary folder, removed afterwards)."""
    own = folder is None
    path = Path(folder or tempfile.mkdtemp(prefix="sbagents-fuzz-"))
    try:
        with Fuzzer(path, **kwargs) as fz:
            fz.prepare()
            yield fz
    finally:
        if own:
            shutil.rmtree(path, ignore_errors=True)


# --- the benchmark --------------------------------------------------------------------------------------------------
def empty_results(seed: int, cases: int, timeout: float, kinds: Sequence[str]) -> dict[str, Any]:
    return {"seed": seed, "cases": cases, "done": 0, "timeout_s": timeout, "memory_limit_mib": MEMORY_LIMIT_MIB,
            "seconds": 0.0, "clean": [], "kinds": {k: {"consumer": CONSUMERS[k], "cases": 0,
                                                        "outcomes": {}, "peak_rss_mib": 0.0, "seconds": 0.0}
                                                   for k in kinds},
            "failures": []}


def record(results: dict[str, Any], case: Case, outcome: Outcome) -> None:
    """Count one case into ``results`` (and list it when it failed)."""
    entry = results["kinds"][case.kind]
    entry["cases"] += 1
    entry["outcomes"][outcome.outcome] = entry["outcomes"].get(outcome.outcome, 0) + 1
    entry["peak_rss_mib"] = max(entry["peak_rss_mib"], outcome.maxrss_mib)
    entry["seconds"] = round(entry["seconds"] + outcome.seconds, 2)
    results["done"] += 1
    if outcome.failed:
        results["failures"].append({**asdict(case), "command": case.command(), **asdict(outcome)})


def measure(args: argparse.Namespace, save: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Run the clean checks and ``args.cases`` cases (or ``args.case`` alone), saving after each when ``save``."""
    from benchmarks.report import machine_info

    kinds = tuple(args.kinds.split(",")) if args.kinds else KINDS
    unknown = set(kinds) - set(KINDS)
    if unknown:
        raise SystemExit(f"error: unknown file kind {', '.join(sorted(unknown))}; known: {', '.join(KINDS)}")
    indices = [args.case] if args.case is not None else list(range(args.cases))
    results = empty_results(args.seed, len(indices), args.timeout, kinds)
    results["machine"] = machine_info()
    start = time.monotonic()
    keep = Path(args.keep).resolve() if args.keep else None
    with fuzzer(Path(args.path) if args.path else None, timeout=args.timeout, bombs=not args.no_bombs,
                keep=keep) as fz:
        fz.keep_all = args.case is not None  # --case: its folder (not the clean runs')
        for case, outcome, fresh in fz.clean:
            results["clean"].append({"command": case.command(), "outcome": outcome.outcome, "fresh_mib": fresh,
                                     "forked_mib": outcome.forked_mib, "seconds": outcome.seconds})
            if outcome.outcome != "ok":
                raise SystemExit(f"error: `{case.command()}` on the files as trained: {outcome.outcome} "
                                 f"{outcome.detail} {outcome.stderr_tail}")
        try:
            for index in indices:
                kind = kinds[index % len(kinds)]
                case, outcome = fz.case(args.seed, index, kind)
                record(results, case, outcome)
                results["seconds"] = round(time.monotonic() - start, 1)
                mark = "" if not outcome.failed else f"  FAILED: {outcome.outcome} {outcome.detail}"
                print(f"case {index} {kind}: {outcome.outcome} ({outcome.seconds:.1f} s, {outcome.maxrss_mib:.0f} MiB)"
                      f"{mark}", file=sys.stderr, flush=True)
                if save is not None:
                    save(results)
        except KeyboardInterrupt:
            results["interrupted"] = True
    results["seconds"] = round(time.monotonic() - start, 1)
    return results


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("`", "'").replace("\n", " ")[:140]


def markdown(result: dict[str, Any]) -> str:
    """The ``fuzz`` section, from the results alone."""
    m = result["machine"]
    kinds = result["kinds"]
    failures = result["failures"]
    total = sum(k["cases"] for k in kinds.values())
    count = lambda entry, names: sum(entry["outcomes"].get(n, 0) for n in names)  # noqa: E731
    bad = [o for o in OUTCOMES if o not in ALLOWED]
    lines = [
        "## Fuzzing the files of a run dir", "",
        f"Machine: {m.get('cpu', '?')}, {m.get('cores', '?')} cores, Python {m.get('python', '?')}, numpy "
        f"{m.get('numpy', '?')}, torch {m.get('torch', '?')}; {m.get('date', '')}. Command: `{result['command']}`"
        f" ({total} cases in {result['seconds'] / 60:.0f} min"
        + (", interrupted" if result.get("interrupted") else "") + ").", "",
        "Each case mutates one file of a trained run (seeded: case I of seed S is `random.Random(\"fuzz:S:I\")`) and "
        "runs the command that reads it in a fresh process. Allowed: loaded (exit 0) or refused in one line (exit "
        f"2). A failure: a signal, a traceback, several lines, another exit code, more than "
        f"{result['memory_limit_mib']} MiB resident, more than {result['timeout_s']:.0f} s, a file written outside "
        "the case's folder, a command run. Harness: `benchmarks/suites/fuzz.py` (its docstring lists the mutations); "
        "`tests/test_fuzz_files.py` runs a few cases of each kind.", "",
        "| file | command | cases | loaded | refused in one line | failures | peak memory |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for kind, entry in kinds.items():
        lines.append(f"| {kind} | {entry['consumer']} | {entry['cases']} | {count(entry, ['ok'])} | "
                     f"{count(entry, ['refused'])} | {count(entry, bad)} | {entry['peak_rss_mib']:.0f} MiB |")
    every = {"outcomes": {o: sum(k["outcomes"].get(o, 0) for k in kinds.values()) for o in OUTCOMES}}
    lines.append(f"| **all** | | {total} | {count(every, ['ok'])} | {count(every, ['refused'])} | "
                 f"{count(every, bad)} | {max((k['peak_rss_mib'] for k in kinds.values()), default=0):.0f} MiB |")
    lines.append("")
    by_outcome = ", ".join(f"{o} {every['outcomes'][o]}" for o in bad if every["outcomes"][o])
    if not failures:
        lines.append(f"No failures in {total} cases.")
        return "\n".join(lines)
    lines += [f"Failures: {by_outcome}. The first {min(len(failures), 25)} (reproduce one with "
              f"`python -m benchmarks run fuzz --seed {result['seed']} --case I --keep DIR`):", "",
              "| case | file | outcome | mutations | stderr, last line |", "|---:|---|---|---|---|"]
    for f in failures[:25]:
        last = (f["stderr_tail"].splitlines() or [""])[-1]
        what = f["outcome"] + (f" ({f['detail']})" if f["detail"] else "")
        lines.append(f"| {f['index']} | {_cell(f['file'])} | {_cell(what)} | {_cell('; '.join(f['mutations']))} | "
                     f"{_cell(last)} |")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=600, help="cases (they cycle through the file kinds)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the mutations")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds a case may run")
    parser.add_argument("--kinds", default="", help=f"comma-separated file kinds (default: all: {','.join(KINDS)})")
    parser.add_argument("--no-bombs", action="store_true", help="no zip members that unpack to hundreds of MiB")
    parser.add_argument("--case", type=int, default=None, help="run only case I of --seed (with --keep: its folder)")
    parser.add_argument("--keep", default=None, help="folder to keep the folders of failed cases in (and --case's)")
    parser.add_argument("--path", default=None, help="sandbox folder (default: a temporary one, removed)")
    parser.add_argument("--progress", default=None,
                        help="file the results are saved to after every case (default: the results file "
                             "benchmarks/results/fuzz.json, none for --smoke; '': none; a scratch run with the "
                             "harness's --results names that file here too)")
    parser.add_argument("--smoke", action="store_true",
                        help="a smoke run: one case per file kind, no bombs, no progress file")
    return parser


def recorded_options(argv: Sequence[str]) -> list[str]:
    """``argv`` without the options that name this machine's folders (``--progress``, ``--keep``, ``--path``)."""
    out: list[str] = []
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg in ("--progress", "--keep", "--path"):
            skip = True
        elif not arg.startswith(("--progress=", "--keep=", "--path=")):
            out.append(shlex.quote(arg))
    return out


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run fuzz [OPTIONS]``: fuzz; the results record the command."""
    args = build_parser().parse_args(list(argv))
    if args.smoke:
        args.cases, args.no_bombs = len(args.kinds.split(",")) if args.kinds else len(KINDS), True
    if args.progress is None:
        args.progress = "" if args.smoke else str(RESULTS_DIR / "fuzz.json")
    command = " ".join(["python -m benchmarks run", SECTION, *recorded_options(argv)])
    progress = Path(args.progress) if args.progress else None

    def save(results: dict[str, Any]) -> None:
        if progress is not None:
            save_results({**results, "command": command}, progress)

    results = measure(args, save)
    results["command"] = command
    return results


BENCHMARKS = (
    Benchmark(name=SECTION, kind="suites", results="fuzz.json",
              summary="seeded mutation fuzzing of model zips, .npz files, configs and monitor CSVs: crashes, "
                      "tracebacks, memory, outside writes",
              run=run, render=markdown),
)
