"""Paging a 2 GB transparency log: :mod:`sbagents.dashboard.logindex` on a plain CSV and on its ``.csv.gz``.

Generates (in a child process, so this process's peak memory is the paging engine's) a SmartHome-like
transparency log: 8 envs, 100-step episodes, the callback's columns (``env, episode, step``, 5 observations, 2
actions, ``reward, terminated, truncated``, info ``comfortable, energy, violation, cost``), floats written with
``%.7g`` like the callback; violations are rare and come in bursts (6 steps of one env in 1 of 250 episode
rounds), as an unsafe episode would. The ``.csv.gz`` is the same rows compressed at level 1 (the callback's level)
as one gzip member. Then, in this process, with an empty index cache (``SBAGENTS_CACHE_DIR`` points to a fresh
folder) and the files in the OS page cache (just written):

- open + first page of 100 rows, cold (no index, no cache);
- a page of 100 rows at the end with no index yet (it indexes the whole file first);
- the full index build (``refresh()``), pages in the middle and at the end once indexed (median of 5);
- a second :class:`LogIndex` of the plain CSV in the same process: it loads the on-disk index cache;
- a violations-only query's first call (``limit=100``, ``time_budget=0.5`` s, what the dashboard asks), the
  whole file scanned for violations cold (block summaries built on the way) and again warm (blocks skipped);
  one episode's rows once the summaries exist;
- the naive baseline: ``csv.reader`` over the file, timed on the first ``--naive-mib`` MiB and extrapolated;
- newline finding, numpy (``np.flatnonzero(np.frombuffer(chunk, np.uint8) == 10)``, the engine's) vs a
  ``bytes.find`` loop, on one 64 MiB chunk;
- peak resident memory of this process (``resource.getrusage``).

    python -m benchmarks run dashboard-paging [--gib 2.0] [--path DIR] [--keep]
"""

from __future__ import annotations

import argparse
import csv
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import Benchmark
from benchmarks.report import machine_info, recorded_argv

SECTION = "dashboard-paging"
N_ENVS = 8
EPISODE_STEPS = 100
BODY_ROWS = 1_000_000  # rows formatted once and reused (with the right env and episode) for every chunk
HEADER = ("env,episode,step,Temperature,Light_Level,Time,Preferred_Temp,Preferred_Light,Action_Temp,Action_Light,"
          "reward,terminated,truncated,comfortable,energy,violation,cost")
PAGE = 100


def _bodies(seed: int = 0) -> list[str]:
    """The cells after ``env,episode`` of :data:`BODY_ROWS` rows (step, observations, actions, ...)."""
    rng = np.random.default_rng(seed)
    n = BODY_ROWS
    i = np.arange(n)
    step = (i // N_ENVS) % EPISODE_STEPS
    env = i % N_ENVS
    temp = rng.normal(22, 2, n)
    light = rng.uniform(0, 100, n)
    hour = (step * 24 // EPISODE_STEPS).astype(float)
    pref_t = rng.normal(22, 1, n)
    pref_l = rng.uniform(20, 80, n)
    a_t = rng.uniform(-1, 1, n)
    a_l = rng.uniform(-10, 10, n)
    energy = np.abs(a_t) + 0.05 * np.abs(a_l)
    reward = -np.abs(temp - pref_t) - 0.5 * np.abs(light - pref_l) / 10 - 0.1 * energy
    comfortable = np.abs(temp - pref_t) < 1.0
    round_ = i // (N_ENVS * EPISODE_STEPS)
    violation = (round_ % 250 == 7) & (env == 3) & (step >= 40) & (step < 46)
    last = step == EPISODE_STEPS - 1
    out = []
    for row in zip(step.tolist(), temp.tolist(), light.tolist(), hour.tolist(), pref_t.tolist(), pref_l.tolist(),
                   a_t.tolist(), a_l.tolist(), reward.tolist(), last.tolist(), comfortable.tolist(), energy.tolist(),
                   violation.tolist(), strict=True):
        s, t, li, h, pt, pl, at, al, r, end, c, e, v = row
        out.append(f"{s},{t:.7g},{li:.7g},{h:.7g},{pt:.7g},{pl:.7g},{at:.7g},{al:.7g},{r:.7g},False,{end},{c},"
                   f"{e:.7g},{'too_hot' if v else ''},{1 if v else 0}\n")
    return out


def generate(folder: Path, gib: float) -> dict[str, Any]:
    """Write ``log.csv`` (about ``gib`` GiB) and ``log.csv.gz`` (the same rows, level 1) into ``folder``."""
    start = time.perf_counter()
    bodies = _bodies()
    target = int(gib * (1 << 30))
    plain, gz = folder / "log.csv", folder / "log.csv.gz"
    comp = zlib.compressobj(1, zlib.DEFLATED, 31)
    written = rows = 0
    envs = [str(e) for e in range(N_ENVS)]
    with open(plain, "wb") as fp, open(gz, "wb") as fz:
        head = (HEADER + "\n").encode()
        fp.write(head)
        fz.write(comp.compress(head))
        written += len(head)
        while written < target:
            base_round = rows // (N_ENVS * EPISODE_STEPS)
            per_round = N_ENVS * EPISODE_STEPS
            text = "".join([f"{envs[i % N_ENVS]},{base_round + i // per_round},{b}" for i, b in enumerate(bodies)])
            data = text.encode()
            final = written + len(data) >= target
            if final:  # cut at a row end near the target
                data = data[: data.rfind(b"\n", 0, target - written) + 1]
            fp.write(data)
            fz.write(comp.compress(data))
            rows += data.count(b"\n")
            written += len(data)
            if final:
                break
        fz.write(comp.flush())
    return {"rows": rows, "bytes": plain.stat().st_size, "gz_bytes": gz.stat().st_size,
            "seconds": round(time.perf_counter() - start, 1)}


def _timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    start = time.perf_counter()
    out = fn()
    return time.perf_counter() - start, out


def _median_time(fn: Callable[[], Any], repeats: int = 5) -> float:
    return statistics.median(_timed(fn)[0] for _ in range(repeats))


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def newline_methods(path: Path, mib: int = 64, block_rows: int = 1024) -> dict[str, float]:
    """Seconds to find every ``block_rows``-th row start in one ``mib`` MiB chunk: numpy vs a bytes.find loop."""
    with open(path, "rb") as fh:
        chunk = fh.read(mib << 20)

    def with_numpy() -> int:
        nl = np.flatnonzero(np.frombuffer(chunk, np.uint8) == 10)
        return len(nl[block_rows - 1 :: block_rows])

    def with_find() -> int:
        found, pos, n = [], chunk.find(b"\n"), 0
        while pos >= 0:
            n += 1
            if n % block_rows == 0:
                found.append(pos + 1)
            pos = chunk.find(b"\n", pos + 1)
        return len(found)

    assert with_numpy() == with_find()
    return {"mib": mib, "numpy_s": _median_time(with_numpy, 3), "bytes_find_s": _median_time(with_find, 3)}


def naive_csv(path: Path, mib: int) -> dict[str, float]:
    """``csv.reader`` over the first ``mib`` MiB of ``path`` (rows counted): seconds and MiB/s."""
    seconds, rows = _timed(lambda: sum(1 for _ in csv.reader(_head_lines(path, mib << 20))))
    return {"mib": mib, "seconds": seconds, "rows": rows, "mib_per_s": mib / seconds}


def _head_lines(path: Path, limit: int) -> Any:
    with open(path, newline="", encoding="utf-8") as fh:
        read = 0
        for line in fh:
            read += len(line)
            if read > limit:
                return
            yield line


def measure(path: Path, rows: int, block_rows: int, violations: bool) -> dict[str, Any]:
    """The figures of one log (plain or gzip); see the module docstring."""
    from sbagents.dashboard.logindex import LogIndex, RowFilter

    out: dict[str, Any] = {"file": path.name, "bytes": path.stat().st_size}
    t, index = _timed(lambda: LogIndex(path, block_rows))
    t_page, page = _timed(lambda: index.page(0, PAGE))
    assert len(page.rows) == PAGE and page.row_numbers[0] == 0
    out["first_page_s"] = t + t_page
    out["first_page_rows_known"] = page.total_rows
    t_end, page = _timed(lambda: LogIndex(path, block_rows).page(rows - PAGE, PAGE))
    assert page.row_numbers[-1] == rows - 1 and page.complete
    out["end_page_no_index_s"] = t_end
    for cached in Path(os.environ["SBAGENTS_CACHE_DIR"]).glob("logindex/*"):
        cached.unlink()  # the index build below starts without a cache
    out["index_s"], _ = _timed(index.refresh)
    assert index.total_rows == rows and index.complete
    out["index_entries"] = len(index._offsets)
    out["checkpoints"] = len(index._checkpoints)
    mid = rows // 2
    out["middle_page_s"] = _median_time(lambda: index.page(mid, PAGE))
    out["end_page_s"] = _median_time(lambda: index.page(rows - PAGE, PAGE))
    if not path.name.endswith(".gz"):
        t_open, second = _timed(lambda: LogIndex(path, block_rows))
        assert second.cache_loaded and second.complete
        t_mid, page = _timed(lambda: second.page(mid, PAGE))
        assert page.row_numbers[0] == mid
        out["cached_open_s"], out["cached_open_middle_page_s"] = t_open, t_open + t_mid
    flt = RowFilter(violations_only=True)
    t_q, page = _timed(lambda: index.query(flt, limit=PAGE, time_budget=0.5))
    out["violations_first_call"] = {"seconds": t_q, "matches": len(page.rows), "scanned_to": page.scanned_to}
    if violations:
        def scan_all() -> int:
            cursor: int | None = 0
            found = 0
            while cursor is not None:
                page = index.query(flt, cursor=cursor, limit=1000, time_budget=5.0)
                found += len(page.rows)
                cursor = page.next_cursor
            return found

        t_cold, found = _timed(scan_all)
        t_warm, found_again = _timed(scan_all)
        assert found == found_again
        out["violations_full_scan"] = {"cold_s": t_cold, "warm_s": t_warm, "matches": found,
                                       "rows_per_s_cold": rows / t_cold}
        episode = (rows // N_ENVS // EPISODE_STEPS) // 2
        t_ep, page = _timed(lambda: index.episode_rows(episode, env=3))
        assert len(page.rows) == EPISODE_STEPS
        out["episode_rows_warm_s"] = t_ep
    out["peak_rss_mib"] = _peak_rss_mib()
    return out


#: The child process that writes the logs (``python -c CHILD FOLDER GIB``), so the parent's peak memory is the engine's.
CHILD = "import sys; from benchmarks.speed.dashboard_paging import generate_child; generate_child(sys.argv[1:])"


def generate_child(argv: list[str]) -> None:
    """Child process: write the logs into ``argv[0]`` (``argv[1]`` GiB) and print what was written as ``k=v``."""
    gen = generate(Path(argv[0]), float(argv[1]))
    print(" ".join(f"{k}={v}" for k, v in gen.items()))


def measure_all(gib: float = 2.0, folder: Path | None = None, keep: bool = False, block_rows: int = 1024,
        naive_mib: int = 256, gzip_too: bool = True) -> dict[str, Any]:
    """Generate the logs (child process), measure both, delete them unless ``keep``."""
    own = folder is None
    work = Path(tempfile.mkdtemp(prefix="dashboard_paging_")) if folder is None else Path(folder)
    work.mkdir(parents=True, exist_ok=True)
    free = shutil.disk_usage(work).free
    if free < gib * 1.6 * (1 << 30) + (1 << 30):
        raise SystemExit(f"{work}: {free / 2**30:.1f} GiB free, need ~{gib * 1.6 + 1:.1f} GiB (use --path)")
    cache = Path(tempfile.mkdtemp(prefix="dashboard_paging_cache_"))
    os.environ["SBAGENTS_CACHE_DIR"] = str(cache)
    try:
        plain, gz = work / "log.csv", work / "log.csv.gz"
        proc = subprocess.run([sys.executable, "-c", CHILD, str(work), str(gib)], check=True, capture_output=True,
                              text=True)
        gen = {k: float(v) if "." in v else int(v) for k, v in (kv.split("=") for kv in proc.stdout.split())}
        import sbagents.dashboard.logindex  # noqa: F401  (imports before the memory baseline)

        result: dict[str, Any] = {"machine": machine_info(), "load": round(os.getloadavg()[0], 2),
                                  "block_rows": block_rows, "generated": gen, "rss_before_mib": _peak_rss_mib()}
        result["newline"] = newline_methods(plain, block_rows=block_rows)
        result["naive_csv"] = naive_csv(plain, naive_mib)
        result["naive_csv"]["extrapolated_full_s"] = gen["bytes"] / (1 << 20) / result["naive_csv"]["mib_per_s"]
        result["plain"] = measure(plain, int(gen["rows"]), block_rows, violations=True)
        if gzip_too:
            result["gzip"] = measure(gz, int(gen["rows"]), block_rows, violations=False)
        result["peak_rss_mib"] = _peak_rss_mib()
        result["load_after"] = round(os.getloadavg()[0], 2)
        return result
    finally:
        shutil.rmtree(cache, ignore_errors=True)
        if not keep:
            for name in ("log.csv", "log.csv.gz"):
                (work / name).unlink(missing_ok=True)
            if own:
                shutil.rmtree(work, ignore_errors=True)


def _ms(seconds: float) -> str:
    return f"{seconds * 1000:,.1f} ms" if seconds < 10 else f"{seconds:,.1f} s"


def markdown(result: dict[str, Any]) -> str:
    """The BENCHMARKS.md section, from the results alone."""
    command = result["command"]
    m, gen, naive, p = result["machine"], result["generated"], result["naive_csv"], result["plain"]
    g = result.get("gzip")
    gib = gen["bytes"] / 2**30
    lines = [
        "## Dashboard: paging a 2 GB transparency log",
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}; {m['date']}, load "
        f"average {result['load']} at the start, {result['load_after']} at the end. Command: `{command}`.",
        "",
        f"A SmartHome-like transparency log generated by the benchmark ({gen['rows']:,} rows, 17 columns, "
        f"{gen['bytes']:,} B = {gib:.2f} GiB; 8 envs, 100-step episodes, violations in rare bursts) and the same "
        f"rows as one gzip member at level 1 ({gen['gz_bytes']:,} B), read through "
        f"`sbagents.dashboard.logindex` (`block_rows={result['block_rows']}`). Cold = a new `LogIndex` with an "
        "empty index cache; the files were just written, so they are in the OS page cache (a cold disk adds its "
        "read time to the first page's first MiB and to every full scan). Pages are 100 rows; times of pages "
        "once indexed are medians of 5.",
        "",
        "| measurement | plain CSV | CSV.gz |",
        "|---|---:|---:|",
    ]

    def row(label: str, key: str) -> None:
        gz = _ms(g[key]) if g is not None and key in g else "-"
        lines.append(f"| {label} | {_ms(p[key]) if key in p else '-'} | {gz} |")

    row("open + first page (cold: no index, no cache)", "first_page_s")
    row("page at the end, no index yet (indexes the whole file)", "end_page_no_index_s")
    row("full index build (`refresh()`)", "index_s")
    row("page in the middle, indexed", "middle_page_s")
    row("page at the end, indexed", "end_page_s")
    row("second `LogIndex` from the disk cache: open", "cached_open_s")
    row("second `LogIndex` from the disk cache: open + page in the middle", "cached_open_middle_page_s")
    vq = p["violations_first_call"]
    gq = g["violations_first_call"] if g is not None else None
    gq_text = f"{_ms(gq['seconds'])}: {gq['matches']} rows, {gq['scanned_to']:,} scanned" if gq else "-"
    lines.append(f"| violations-only query, first call (limit 100, budget 0.5 s) | {_ms(vq['seconds'])}: "
                 f"{vq['matches']} rows, {vq['scanned_to']:,} scanned | {gq_text} |")
    full = p.get("violations_full_scan")
    if full:
        lines.append(f"| violations over the whole file: cold (builds block summaries) / warm (skips blocks) | "
                     f"{_ms(full['cold_s'])} / {_ms(full['warm_s'])} ({full['matches']:,} rows; "
                     f"{full['rows_per_s_cold']:,.0f} rows/s cold) | - |")
        lines.append(f"| one episode's rows (`episode_rows`, middle of the file, summaries built) | "
                     f"{_ms(p['episode_rows_warm_s'])} | - |")
    gz_entries = f"{g['index_entries']:,} offsets + {g['checkpoints']} checkpoints" if g is not None else "-"
    lines.append(f"| index size in memory | {p['index_entries']:,} offsets ({p['index_entries'] * 8 / 2**10:,.0f} "
                 f"KiB) | {gz_entries} |")
    ratio = naive["extrapolated_full_s"] / p["first_page_s"]
    nl = result["newline"]
    lines += [
        "",
        f"Naive baseline: `csv.reader` over the file ran at {naive['mib_per_s']:,.0f} MiB/s on its first "
        f"{naive['mib']} MiB ({naive['rows']:,} rows in {naive['seconds']:.2f} s), so reading the whole "
        f"{gib:.2f} GiB file that way would take ~{naive['extrapolated_full_s']:,.0f} s (extrapolated, not run; "
        f"keeping its rows as lists would need many GiB): the first page comes **{ratio:,.0f}x** sooner. "
        f"Peak resident memory of the measuring process: {result['peak_rss_mib']:,.0f} MiB "
        f"({result['rss_before_mib']:,.0f} MiB after the imports, before the first open); the logs are generated "
        "in a child process. Newline finding in one "
        f"{nl['mib']} MiB chunk: numpy {nl['numpy_s'] * 1000:,.0f} ms, a `bytes.find` loop "
        f"{nl['bytes_find_s'] * 1000:,.0f} ms ({nl['bytes_find_s'] / nl['numpy_s']:.1f}x slower): the index uses "
        "numpy. The gzip log has no disk cache (zlib decompressor states cannot be saved with the standard "
        "library); its pages decompress from the in-memory checkpoint (every 16 MiB of output) before them.",
    ]
    return "\n".join(lines)


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run dashboard-paging [OPTIONS]``: measure; the results record the command."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gib", type=float, default=2.0, help="size of the plain log in GiB")
    parser.add_argument("--path", default=None, help="folder for the generated logs (default: a temp folder)")
    parser.add_argument("--keep", action="store_true", help="keep the generated logs")
    parser.add_argument("--block-rows", type=int, default=1024, help="LogIndex block_rows")
    parser.add_argument("--naive-mib", type=int, default=256, help="MiB read by the csv.reader baseline")
    parser.add_argument("--no-gzip", action="store_true", help="measure the plain CSV only")
    args = parser.parse_args(list(argv))
    result = measure_all(args.gib, None if args.path is None else Path(args.path), args.keep, args.block_rows,
                         args.naive_mib, not args.no_gzip)
    kept = [a for i, a in enumerate(argv) if "--path" not in (a, argv[i - 1] if i else "")]  # no machine paths
    result["command"] = " ".join(["python -m benchmarks run", SECTION, *recorded_argv(kept)])
    return result


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="dashboard_paging.json",
              summary="dashboard LogIndex paging a 2 GB transparency log, plain CSV and CSV.gz",
              run=run, render=markdown),
)
