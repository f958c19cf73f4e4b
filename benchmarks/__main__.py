"""``python -m benchmarks``: run the benchmark suite and update ``BENCHMARKS.md``.

Suites, in this order, each writing its Markdown between its own markers (``<!-- NAME:start -->`` /
``<!-- NAME:end -->``) so the other sections of the file stay:

- ``speed`` (section ``speed``, :mod:`benchmarks.speed`): env steps/s (single env, reference VecEnv x64,
  batched x64) and PPO training fps for GridWorld and TreasureHunt;
- ``callbacks`` (``callback-overhead``, :mod:`benchmarks.callback_overhead`): PPO fps with / without the
  trust callbacks (16,384 steps, ``--rounds`` interleaved repeats);
- ``export`` (``export-latency``, :mod:`benchmarks.export_latency`): SmartHome DDPG after 2,000 training
  steps, ONNX fp32 / int8 file sizes, parity and p50/p99 latency against ``model.predict``;
- ``learning`` (``recorded-learning``, :mod:`benchmarks.recorded`): the learning results recorded in
  ``benchmarks/results/`` (reads files only; regenerate them with the commands the table shows).

``--quick`` runs shorter measurements (a smoke run, noisier numbers): speed's quick mode, callbacks 4,096
steps x 1 repeat, export without training and 200 latency calls. Ratios are always measured in one run.
Run time, measured with ``--quick`` on the shared 2-core machine (load ~3): 24 s wall (speed 10 s,
callbacks 7 s, export and learning < 1 s each, ~6 s of imports). The default suite, extrapolated from
that (callbacks: 24 runs x 16,384 steps + warm-up at the ~5k steps/s wall measured there; export: 2,000
DDPG steps, measured 7 s; speed: ~4x its quick run, 19 s recorded on a quiet machine): ~2 min on the
loaded machine, about half of that on a quiet one; each extra ``--rounds`` adds ~25 s of callbacks.

    python -m benchmarks                                # everything, into BENCHMARKS.md
    python -m benchmarks --quick --output SCRATCH.md   # smoke run (keeps BENCHMARKS.md as it is)
    python -m benchmarks --only callbacks export --rounds 5
"""

from __future__ import annotations

import argparse
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path

from benchmarks import callback_overhead, export_latency, recorded, speed

SUITES: tuple[str, ...] = ("speed", "callbacks", "export", "learning")


def json_paths(json_arg: str) -> dict[str, str | None]:
    """Raw-results file per suite for ``--json``: a folder (``speed.json``, ``callback_overhead.json``,
    ``export_latency.json`` in it), or a ``.json`` file for speed with the others next to it; ``''``: none."""
    if not json_arg:
        return dict.fromkeys(SUITES)
    path = Path(json_arg)
    folder, speed_name = (path.parent, path.name) if path.suffix == ".json" else (path, "speed.json")
    return {"speed": str(folder / speed_name), "callbacks": str(folder / "callback_overhead.json"),
            "export": str(folder / "export_latency.json"), "learning": None}


def suite_commands(output: str, json_arg: str, rounds: int, quick: bool) -> dict[str, Callable[[], object]]:
    """The suites as zero-argument callables that measure, print and write their section into ``output``."""
    jsons = json_paths(json_arg)

    def opt(suite: str) -> list[str]:
        path = jsons[suite]
        return ["--json", path] if path else []

    cb_args = ["--timesteps", "4096", "--repeats", "1"] if quick else ["--repeats", str(rounds)]
    ex_args = ["--train-steps", "0", "--latency-n", "200", "--n-observations", "200"] if quick else []
    return {
        "speed": lambda: speed.main(output=output, json_path=jsons["speed"], rounds=rounds, quick=quick),
        "callbacks": lambda: callback_overhead.main([*cb_args, "--output", output, *opt("callbacks")]),
        "export": lambda: export_latency.main([*ex_args, "--output", output, *opt("export")]),
        "learning": lambda: recorded.main(["--output", output]),
    }


def run_suites(
    only: Sequence[str], output: str, json_arg: str = "", rounds: int = 3, quick: bool = False
) -> tuple[dict[str, float], list[str]]:
    """Run the suites in ``only`` (in :data:`SUITES` order).

    :return: wall seconds per suite, and the names of the suites that failed (their traceback goes to
        stderr; the other suites still run).
    """
    commands = suite_commands(output, json_arg, rounds, quick)
    seconds: dict[str, float] = {}
    failed: list[str] = []
    for name in (s for s in SUITES if s in only):
        print(f"\n=== {name} ===", flush=True)
        start = time.perf_counter()
        try:
            commands[name]()
        except Exception:
            traceback.print_exc()
            failed.append(name)
        seconds[name] = time.perf_counter() - start
    return seconds, failed


def build_parser() -> argparse.ArgumentParser:
    """Arguments of ``python -m benchmarks``."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update")
    parser.add_argument("--json", default=None,
                        help="folder for the raw results, or the speed .json file; '' to skip "
                        "(default: benchmarks/results, nothing with --quick)")
    parser.add_argument("--rounds", type=int, default=3,
                        help="interleaved rounds per figure (median); also the callback-overhead repeats")
    parser.add_argument("--quick", action="store_true", help="short measurements (smoke run)")
    parser.add_argument("--only", nargs="+", action="extend", choices=SUITES, default=None,
                        help="run only these suites (repeatable; default: all)")
    return parser


def main(argv: list[str] | None = None) -> None:
    """Run the selected suites; exit with status 1 if any failed."""
    args = build_parser().parse_args(argv)
    if args.rounds < 1:
        raise SystemExit("--rounds must be >= 1")
    json_arg = args.json if args.json is not None else ("" if args.quick else "benchmarks/results")
    seconds, failed = run_suites(args.only or SUITES, args.output, json_arg, args.rounds, args.quick)
    summary = ", ".join(f"{k} {v:.0f} s{' (FAILED)' if k in failed else ''}" for k, v in seconds.items())
    print(f"\nbenchmarks: {summary}; total {sum(seconds.values()):.0f} s -> {args.output}")
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
