"""sbagents.dashboard.logindex: paging, growing and gzip logs, filters, the on-disk index cache."""

from __future__ import annotations

import csv
import gzip
import io
import json
import os
import threading
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sbagents.dashboard import logindex, logsources
from sbagents.dashboard.logindex import LogIndex, RowFilter
from sbagents.dashboard.logregistry import open_log

HEADER = ["env", "episode", "step", "obs_0", "action_0", "reward", "terminated", "truncated", "event", "violation",
          "cost"]


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SBAGENTS_CACHE_DIR", str(tmp_path / "cache"))


def synthetic_text(n_rows: int, seed: int = 0, n_envs: int = 3, header: list[str] | None = None,
                   quotes: bool = True) -> str:
    """A transparency-style CSV: ``n_envs`` envs stepping together, episodes of 5-30 steps, rare violations and
    costs, quoted info strings."""
    rng = np.random.default_rng(seed)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header or HEADER)
    episode, step, length = [0] * n_envs, [0] * n_envs, [int(rng.integers(5, 30)) for _ in range(n_envs)]
    for i in range(n_rows):
        e = i % n_envs
        done = step[e] + 1 >= length[e]
        violation = "too_hot" if rng.random() < 0.03 else ""
        cost = f"{rng.random():.3g}" if rng.random() < 0.03 else "0"
        event = ["", "goal", "a,b", 'say "hi"'][int(rng.integers(0, 4 if quotes else 2))]
        writer.writerow([e, episode[e], step[e], f"{rng.normal():.4g}", int(rng.integers(0, 4)),
                         f"{rng.normal():.5g}", done, False, event, violation, cost])
        step[e] += 1
        if done:
            episode[e], step[e], length[e] = episode[e] + 1, 0, int(rng.integers(5, 30))
    return out.getvalue()


def expected_rows(text: str) -> tuple[list[str], list[list[str]]]:
    rows = list(csv.reader(text.splitlines()))
    return rows[0], rows[1:]


def write(path: Path, text: str) -> Path:
    if path.suffix == ".gz":
        with gzip.open(path, "wb", compresslevel=1) as fh:
            fh.write(text.encode())
    else:
        path.write_bytes(text.encode())
    return path


def all_rows(index: LogIndex) -> list[list[str]]:
    return index.page(0, 10**9).rows


def brute(rows: list[list[str]], columns: list[str], flt: RowFilter) -> list[int]:
    """Row numbers matching ``flt`` by a plain Python loop over parsed rows."""
    col = {c.lower(): i for i, c in enumerate(columns)}

    def num(r: list[str], name: str) -> float | None:
        try:
            return float(r[col[name]])
        except (KeyError, ValueError):
            return None

    out = []
    for n, r in enumerate(rows):
        ok = True
        if flt.episode is not None:
            ok &= num(r, "episode") == flt.episode
        if flt.env is not None:
            ok &= num(r, "env") == flt.env
        if flt.agent is not None:
            ok &= "agent" in col and r[col["agent"]] == flt.agent
        step, reward = num(r, "step"), num(r, "reward")
        if flt.step_min is not None:
            ok &= step is not None and step >= flt.step_min
        if flt.step_max is not None:
            ok &= step is not None and step <= flt.step_max
        if flt.reward_min is not None:
            ok &= reward is not None and reward >= flt.reward_min
        if flt.reward_max is not None:
            ok &= reward is not None and reward <= flt.reward_max
        if flt.violations_only:
            cost = num(r, "cost")
            ok &= ("violation" in col and r[col["violation"]] != "") or (cost is not None and cost > 0)
        if ok:
            out.append(n)
    return out


def query_all(index: LogIndex, flt: RowFilter, limit: int, time_budget: float = 0.0) -> list[int]:
    """Every match by following ``next_cursor`` (a 0 s budget: one block per call)."""
    cursor: int | None = 0
    numbers: list[int] = []
    calls = 0
    while cursor is not None:
        page = index.query(flt, cursor=cursor, limit=limit, time_budget=time_budget)
        assert len(page.rows) == len(page.row_numbers) <= limit
        assert page.next_cursor is None or page.next_cursor > cursor
        numbers += page.row_numbers
        cursor = page.next_cursor
        calls += 1
        assert calls < 10_000
    return numbers


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz"])
@pytest.mark.parametrize("block_rows", [1, 7, 64, 1024])
def test_pages_equal_csv_reader(tmp_path: Path, suffix: str, block_rows: int) -> None:
    text = synthetic_text(700)
    header, rows = expected_rows(text)
    index = LogIndex(write(tmp_path / f"log{suffix}", text), block_rows=block_rows)
    first = index.page(0, 5)
    assert first.columns == header == index.columns and first.rows == rows[:5]
    assert first.row_numbers == [0, 1, 2, 3, 4] and first.next_cursor == 5
    for start in (0, 1, 6, 7, 13, 63, 64, 65, 127, 128, 500, 695, 699, 700, 750):
        for count in (1, 7, 64, 65, 200):
            page = index.page(start, count)
            assert page.rows == rows[start : start + count], (start, count)
            assert page.row_numbers == list(range(start, min(start + count, 700)))
    index.refresh()
    assert index.total_rows == 700 and index.complete
    end = index.page(650, 100)
    assert end.rows == rows[650:] and end.next_cursor is None and end.total_rows == 700
    assert all_rows(index) == rows
    assert index.tail(3).rows == rows[-3:] and index.tail(3).row_numbers == [697, 698, 699]
    assert index.tail(10_000).rows == rows


def test_first_page_without_full_scan(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """page(0, n) indexes only the first chunk; a later page indexes just as far as it needs."""
    text = synthetic_text(20_000)
    _, rows = expected_rows(text)
    size = len(text.encode())
    monkeypatch.setattr(logindex, "CHUNK_BYTES", 64 << 10)
    monkeypatch.setattr(logindex, "FIRST_STEP_BYTES", 32 << 10)
    index = LogIndex(write(tmp_path / "big.csv", text), block_rows=100)
    assert index.page(0, 10).rows == rows[:10]
    assert not index.complete and 0 < index.bytes_scanned < size / 4 and index.total_rows < 20_000
    assert index.page(5000, 10).rows == rows[5000:5010]
    assert not index.complete and index.bytes_scanned < size
    index.refresh(time_budget=0.0)  # one step at least, not necessarily the whole file
    index.refresh()
    assert index.complete and index.bytes_scanned == size and index.total_rows == 20_000


def test_multi_member_gzip(tmp_path: Path) -> None:
    text = synthetic_text(400)
    lines = text.splitlines(keepends=True)
    path = tmp_path / "m.csv.gz"
    for part in (lines[:1], lines[1:150], lines[150:151], lines[151:]):  # one member per append
        with gzip.open(path, "ab", compresslevel=1) as fh:
            fh.write("".join(part).encode())
    index = LogIndex(path, block_rows=16)
    _, rows = expected_rows(text)
    assert all_rows(index) == rows and index.complete
    assert len([c for c in index._checkpoints if c.state is None]) >= 4  # a checkpoint per member start
    assert index.page(140, 20).rows == rows[140:160]


def test_checkpoints_in_large_gzip(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Pages decompress from the checkpoint before them (decompressor copies), not from the file start."""
    monkeypatch.setattr(logsources, "CHECKPOINT_BYTES", 20_000)
    monkeypatch.setattr(logsources, "GZ_READ_BYTES", 4096)
    monkeypatch.setattr(logsources, "GZ_MAX_OUT", 8192)
    text = synthetic_text(8000)
    _, rows = expected_rows(text)
    index = LogIndex(write(tmp_path / "c.csv.gz", text), block_rows=50)
    index.refresh()
    assert len([c for c in index._checkpoints if c.state is not None]) > 10
    for start in (0, 49, 50, 3333, 7990, 4000, 10):
        assert index.page(start, 75).rows == rows[start : start + 75]
    assert query_all(index, RowFilter(violations_only=True), 17) == brute(rows, index.columns,
                                                                           RowFilter(violations_only=True))


def test_truncated_and_growing_gzip(tmp_path: Path) -> None:
    """A sync-flushed, unfinished member (training still running) and a tail cut anywhere never raise: every row
    that decompresses completely is returned, and rows appended later appear after refresh()."""
    text = synthetic_text(300)
    _, rows = expected_rows(text)
    lines = text.splitlines(keepends=True)
    live = tmp_path / "live.csv.gz"
    raw = open(live, "ab")  # noqa: SIM115
    writer = gzip.GzipFile(fileobj=raw, mode="ab", compresslevel=1)
    writer.write("".join(lines[:101]).encode())
    writer.flush()  # Z_SYNC_FLUSH, as the callback does while training runs
    raw.flush()
    writer.write(lines[101].encode()[:10])  # buffered in zlib, not on disk yet
    index = LogIndex(live, block_rows=8)
    assert all_rows(index) == rows[:100] and index.complete
    writer.write("".join(lines[101:])[10:].encode())
    writer.flush()
    raw.flush()
    index.refresh()
    assert index.total_rows == 300 and all_rows(index) == rows
    writer.close()
    raw.close()
    full = live.read_bytes()
    for cut in (5, 30, len(full) // 3, len(full) // 2, len(full) - 9, len(full) - 1):
        part = tmp_path / f"cut{cut}.csv.gz"
        part.write_bytes(full[:cut])
        decompressed = zlib.decompressobj(wbits=31).decompress(full[:cut])
        n_complete = max(decompressed.count(b"\n") - 1, 0)
        index = LogIndex(part, block_rows=8)
        got = all_rows(index)
        assert got == rows[:n_complete] and index.complete
        assert index.tail(2).rows == rows[:n_complete][-2:]
    garbage = tmp_path / "garbage.csv.gz"
    garbage.write_bytes(full + b"not gzip at all")
    assert all_rows(LogIndex(garbage)) == rows


def test_partial_last_line_plain(tmp_path: Path) -> None:
    text = synthetic_text(50)
    _, rows = expected_rows(text)
    lines = text.splitlines(keepends=True)
    path = tmp_path / "p.csv"
    path.write_text("".join(lines[:41]) + lines[41][:7])
    index = LogIndex(path, block_rows=4)
    assert all_rows(index) == rows[:40] and index.total_rows == 40 and index.complete
    assert index.tail(1).rows == [rows[39]]
    with open(path, "a") as fh:
        fh.write(lines[41][7:] + lines[42])
    assert index.total_rows == 40  # nothing known before a refresh...
    index.refresh()
    assert all_rows(index) == rows[:42] and index.page(41, 5).rows == [rows[41]]
    with open(path, "a") as fh:
        fh.write("".join(lines[43:]))
    assert index.page(45, 3).rows == rows[45:48]  # ...or a page beyond the known rows
    index.refresh()
    assert all_rows(index) == rows


FILTERS = [
    RowFilter(episode=3),
    RowFilter(env=1),
    RowFilter(episode=2, env=0),
    RowFilter(step_min=4, step_max=6),
    RowFilter(step_min=20),
    RowFilter(reward_min=0.5),
    RowFilter(reward_min=-0.2, reward_max=0.1, env=2),
    RowFilter(violations_only=True),
    RowFilter(violations_only=True, env=1, step_max=10),
    RowFilter(episode=10_000),
    RowFilter(agent="a"),  # no agent column: nothing
]


@pytest.mark.parametrize(("suffix", "quotes"), [(".csv", True), (".csv.gz", True), (".csv", False)])
def test_filters_and_cursor_continuation(tmp_path: Path, suffix: str, quotes: bool) -> None:
    """Quoted cells: blocks parsed with csv; none: cells located with numpy (logindex._SplitBlock)."""
    text = synthetic_text(3000, seed=1, quotes=quotes)
    header, rows = expected_rows(text)
    index = LogIndex(write(tmp_path / f"f{suffix}", text), block_rows=64)
    for flt in FILTERS:
        expected = brute(rows, header, flt)
        assert query_all(index, flt, limit=13) == expected, flt
        assert query_all(index, flt, limit=13) == expected, flt  # again, now skipping summarized blocks
        page = index.query(flt, limit=10**6, time_budget=60)
        assert page.row_numbers == expected and page.next_cursor is None and page.scanned_to == 3000
        assert page.rows == [rows[i] for i in expected]
    assert index._summaries and RowFilter().is_empty() and not RowFilter(violations_only=True).is_empty()
    assert index.query(RowFilter(), cursor=10, limit=5).rows == rows[10:15]
    ep = index.episode_rows(4, env=2)
    assert ep.row_numbers == brute(rows, header, RowFilter(episode=4, env=2)) and ep.next_cursor is None
    capped = index.episode_rows(4, max_rows=3)
    assert capped.row_numbers == brute(rows, header, RowFilter(episode=4))[:3] and capped.next_cursor is not None


def test_split_block_equals_csv_parse() -> None:
    """The numpy cell locator gives the cells csv gives: integers, floats, empty and odd cells."""
    text = synthetic_text(300, seed=3, quotes=False).split("\n", 1)[1]
    text += "1,,7,x,3,,False,False,,,0\n2,12,-3,1e-3,0,nan,True,False,goal,v,-1\n"
    data = text.encode()
    n_rows, n_cols = text.count("\n"), len(HEADER)
    fast = logindex._SplitBlock.make(data, n_rows, n_cols)
    slow = logindex._ParsedBlock(logindex._parse_lines(data, n_cols))
    assert fast is not None and fast.n == slow.n == n_rows
    for col in range(n_cols):
        np.testing.assert_array_equal(fast.numbers(col), slow.numbers(col))
        assert fast.strings(col) == slow.strings(col)
        np.testing.assert_array_equal(fast.nonempty(col), slow.nonempty(col))
    assert fast.take([0, 5, n_rows - 1]) == slow.take([0, 5, n_rows - 1])
    assert logindex._SplitBlock.make(data + b"1,2\n", n_rows + 1, n_cols) is None  # a short row: csv instead
    assert logindex._SplitBlock.make(b'1,"a",2\n', 1, 3) is None


@pytest.mark.parametrize("columns", [["violation"], ["cost"], []])
def test_violations_only_with_either_column(tmp_path: Path, columns: list[str]) -> None:
    keep = [c for c in HEADER if c not in ("violation", "cost")] + columns
    text = synthetic_text(500, seed=2)
    full_header, full_rows = expected_rows(text)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(keep)
    writer.writerows([[r[full_header.index(c)] for c in keep] for r in full_rows])
    header, rows = expected_rows(out.getvalue())
    index = LogIndex(write(tmp_path / "v.csv", out.getvalue()), block_rows=32)
    expected = brute(rows, header, RowFilter(violations_only=True))
    assert bool(expected) == bool(columns)
    assert query_all(index, RowFilter(violations_only=True), 7) == expected


def test_disk_cache_reused_grown_and_invalidated(tmp_path: Path) -> None:
    text = synthetic_text(2000)
    _, rows = expected_rows(text)
    path = write(tmp_path / "c.csv", text)
    first = LogIndex(path, block_rows=32)
    first.refresh()
    assert not first.cache_loaded and first.bytes_scanned == path.stat().st_size
    assert list((tmp_path / "cache" / "logindex").glob("*.npz"))
    second = LogIndex(path, block_rows=32)
    assert second.cache_loaded and second.complete and second.total_rows == 2000
    second.refresh()
    assert second.bytes_scanned == 0 and second.page(1500, 40).rows == rows[1500:1540]
    more = synthetic_text(2300).splitlines(keepends=True)[2001:]  # the same generator, 300 more rows
    with open(path, "a") as fh:
        fh.write("".join(more))
    grown = LogIndex(path, block_rows=32)
    assert grown.cache_loaded
    grown.refresh()
    _, rows_grown = expected_rows(synthetic_text(2300))
    assert grown.bytes_scanned == len("".join(more).encode()) and all_rows(grown) == rows_grown
    short = synthetic_text(100, seed=5)
    replacement = write(tmp_path / "tmp.csv", short)
    os.replace(replacement, path)  # another file (inode) at the same path
    fresh = LogIndex(path, block_rows=32)
    assert not fresh.cache_loaded and all_rows(fresh) == expected_rows(short)[1]
    path.write_text(text[: len(text) // 3])  # truncated in place (same inode, shorter): the cache is not used
    LogIndex(path, block_rows=32).refresh()
    path.write_text(short)
    again = LogIndex(path, block_rows=32)
    assert not again.cache_loaded and all_rows(again) == expected_rows(short)[1]
    other = synthetic_text(300, seed=6)  # rewritten in place with other, longer content: hashes differ
    path.write_text(other)
    rewritten = LogIndex(path, block_rows=32)
    assert not rewritten.cache_loaded and all_rows(rewritten) == expected_rows(other)[1]


def test_open_log_shared_and_reindexed(tmp_path: Path) -> None:
    text = synthetic_text(1500)
    _, rows = expected_rows(text)
    path = write(tmp_path / "o.csv.gz", text)
    results: list[Any] = []

    def worker(start: int) -> None:
        index = open_log(path)
        index.refresh(time_budget=0.01)
        results.append((index, index.page(start, 50).rows == rows[start : start + 50]))

    threads = [threading.Thread(target=worker, args=(i * 97,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len({id(r[0]) for r in results}) == 1 and all(r[1] for r in results)
    index = open_log(tmp_path / "." / "o.csv.gz")
    assert index is results[0][0]
    short = synthetic_text(40, seed=9)
    write(tmp_path / "new.csv.gz", short)
    os.replace(tmp_path / "new.csv.gz", path)
    replaced = open_log(path)
    assert replaced is not index and all_rows(replaced) == expected_rows(short)[1]
    index.refresh()  # the old object re-indexes the replaced file too
    assert all_rows(index) == expected_rows(short)[1]


def test_book_format_headers(tmp_path: Path) -> None:
    header = ["Episode", "Step", "Temperature", "Action_Temp", "Reward"]
    lines = [",".join(header)] + [f"{i // 10},{i % 10},{20 + i % 7}.5,{(i % 3) - 1},{-(i % 11) / 4}"
                                  for i in range(95)]
    text = "\n".join(lines) + "\n"
    _, rows = expected_rows(text)
    index = LogIndex(write(tmp_path / "book.csv", text), block_rows=16)
    assert index.columns == header and all_rows(index) == rows
    for flt in (RowFilter(episode=3), RowFilter(step_min=8), RowFilter(reward_max=-2.0, episode=5),
                RowFilter(violations_only=True), RowFilter(env=0)):
        assert query_all(index, flt, 4) == brute(rows, header, flt), flt
    assert index.episode_rows(7).row_numbers == list(range(70, 80))


def test_real_callback_logs(tmp_path: Path) -> None:
    """Logs written by TransparencyCSVCallback (plain and gzip, appended by a second learn, multi-agent, book)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    from sbagents.callbacks import TransparencyCSVCallback

    torch.set_num_threads(1)
    kwargs: dict[str, Any] = {"n_steps": 40, "batch_size": 60, "n_epochs": 1, "seed": 0,
                              "policy_kwargs": {"net_arch": [8]}}
    for name in ("grid.csv", "grid.csv.gz"):
        path = tmp_path / name
        model = PPO("MlpPolicy", make_vec_env("sbagents/GridWorld-v0", n_envs=3, seed=0), **kwargs)
        model.learn(120, callback=TransparencyCSVCallback(path))
        model.learn(120, callback=TransparencyCSVCallback(path))  # gzip: a second member
        opener: Any = gzip.open if name.endswith(".gz") else open
        with opener(path, "rt", newline="") as fh:
            header, rows = expected_rows(fh.read())
        index = LogIndex(path, block_rows=16)
        assert index.columns == header and all_rows(index) == rows and len(rows) == 240
        assert index.episode_rows(1, env=2).row_numbers == brute(rows, header, RowFilter(episode=1, env=2))

    from sbagents.envs import treasure_hunt_v0
    from sbagents.multiagent.parameter_sharing import make_parameter_sharing_vec_env

    venv = make_parameter_sharing_vec_env(treasure_hunt_v0.parallel_env, n_envs=2, seed=0)
    path = tmp_path / "team.csv"
    PPO("MlpPolicy", venv, **{**kwargs, "n_steps": 60}).learn(60 * venv.num_envs,
                                                              callback=TransparencyCSVCallback(path))
    header, rows = expected_rows(path.read_text())
    index = LogIndex(path, block_rows=32)
    assert header[:4] == ["env", "agent", "episode", "step"] and all_rows(index) == rows
    agent = rows[1][1]
    flt = RowFilter(agent=agent, env=1, step_min=10, step_max=30)
    expected = brute(rows, header, flt)
    assert expected and query_all(index, flt, 5) == expected
    assert index.episode_rows(0, env=0, agent=agent).row_numbers == brute(
        rows, header, RowFilter(episode=0, env=0, agent=agent))

    from sbagents.envs.smart_home import SmartHomeEnv

    book = tmp_path / "book.csv"
    PPO("MlpPolicy", make_vec_env(SmartHomeEnv, n_envs=1, seed=2), **{**kwargs, "n_steps": 64, "batch_size": 64}
        ).learn(128, callback=TransparencyCSVCallback(book, book_header=True))
    header, rows = expected_rows(book.read_text())
    index = LogIndex(book, block_rows=10)
    assert header[:2] == ["Episode", "Step"] and all_rows(index) == rows
    flt = RowFilter(step_min=50, reward_max=-1.0)
    assert query_all(index, flt, 9) == brute(rows, header, flt)


def test_benchmark_generator_and_section(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """benchmarks.speed.dashboard_paging writes the same rows plain and gzipped, episodes numbered as the callback
    numbers them; BENCHMARKS.md's section is what its markdown() makes of the saved results."""
    from benchmarks.speed import dashboard_paging as bench

    monkeypatch.setattr(bench, "BODY_ROWS", 6400)
    gen = bench.generate(tmp_path, 0.002)
    plain, gz = (tmp_path / "log.csv").read_bytes(), gzip.decompress((tmp_path / "log.csv.gz").read_bytes())
    assert plain == gz and gen["rows"] == plain.count(b"\n") - 1 and gen["bytes"] == len(plain) <= 0.002 * 2**30
    header, rows = expected_rows(plain.decode())
    assert header == bench.HEADER.split(",") and len(rows) > 6400  # the body rows are reused
    for n, r in enumerate(rows):
        assert (int(r[0]), int(r[1]), int(r[2])) == (n % 8, n // 800, (n // 8) % 100)
    index = LogIndex(tmp_path / "log.csv.gz", block_rows=64)
    assert all_rows(index) == rows
    violations = brute(rows, header, RowFilter(violations_only=True))
    assert violations and query_all(index, RowFilter(violations_only=True), 5) == violations

    root = Path(__file__).resolve().parents[1]
    saved = json.loads((root / "benchmarks" / "results" / "dashboard_paging.json").read_text())
    text = (root / "BENCHMARKS.md").read_text()
    start, end = "<!-- dashboard-paging:start -->", "<!-- dashboard-paging:end -->"
    assert text.count(start) == 1 and text.count(end) == 1
    assert bench.markdown(saved).strip() == text[text.index(start) + len(start) : text.index(end)].strip()
    assert saved["plain"]["first_page_s"] < saved["naive_csv"]["extrapolated_full_s"]


def test_benchmark_tiny_run_renders_its_rows(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``python -m benchmarks run dashboard-paging`` on a 2 MiB log: every row of the section, no machine path."""
    from benchmarks.speed import dashboard_paging as bench

    monkeypatch.setattr(bench.shutil, "disk_usage", lambda path: type("U", (), {"free": 2**40})())
    result = bench.run(["--gib", "0.002", "--naive-mib", "1", "--path", str(tmp_path / "logs")])
    assert result["command"] == "python -m benchmarks run dashboard-paging --gib 0.002 --naive-mib 1"
    text = bench.markdown(result)
    assert "| full index build (`refresh()`) |" in text and "| index size in memory |" in text
    assert str(tmp_path) not in text
