"""Files written into a run dir are complete or absent: a write cut short (an exception, ``kill -9``, a full disk)
never leaves a file under its final name, and a full disk is one line naming the file (exit 2)."""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest
from cli_helpers import cli, run_main

from sbagents.atomic import write_bytes, write_with
from sbagents.errors import UsageError
from sbagents.safe_load import read_model_data


def test_a_failed_write_keeps_the_old_file(tmp_path: Path) -> None:
    path = write_bytes(tmp_path / "summary.json", b"old")

    def half_then_fail(tmp: Path) -> None:
        tmp.write_bytes(b"ne")
        raise RuntimeError("cut short")

    with pytest.raises(RuntimeError):
        write_with(path, half_then_fail)
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]  # no temporary file left


def test_a_full_disk_names_the_file_and_replaces_nothing(tmp_path: Path) -> None:
    path = write_bytes(tmp_path / "model.zip", b"complete")

    def disk_full(tmp: Path) -> None:
        tmp.write_bytes(b"par")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with pytest.raises(UsageError, match=r"cannot write .*model\.zip: No space left on device; nothing was replaced"):
        write_with(path, disk_full)
    assert path.read_bytes() == b"complete" and len(list(tmp_path.iterdir())) == 1


def test_kill_9_mid_write_leaves_no_file_under_the_final_name(tmp_path: Path) -> None:
    target = tmp_path / "best_model.zip"
    script = textwrap.dedent(f"""
        import os, signal
        from pathlib import Path
        from sbagents.atomic import write_with

        def half_then_killed(tmp: Path) -> None:
            tmp.write_bytes(b"half")
            os.kill(os.getpid(), signal.SIGKILL)

        write_with(Path({str(target)!r}), half_then_killed)
    """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=120)
    assert result.returncode == -signal.SIGKILL
    assert not target.exists()


def test_kill_9_during_a_checkpoint(tmp_path: Path) -> None:
    """Training killed while writing its first checkpoint: no checkpoint zip that looks complete, and asking for it
    is one line."""
    script = textwrap.dedent("""
        import os, signal, sys
        import sbagents.atomic as atomic
        from sbagents.train import main

        fsync = atomic._fsync

        def killed_mid_checkpoint(path):
            name = path.name
            if name.startswith(".rl_model_") and name.endswith(".partial") and "vecnormalize" not in name:
                os.kill(os.getpid(), signal.SIGKILL)  # the zip's data is written, not yet renamed
            fsync(path)

        atomic._fsync = killed_mid_checkpoint
        main(sys.argv[1:])
    """)
    logs = tmp_path / "logs"
    args = ["--algo", "ppo", "--env", "GridWorld-v0", "-f", str(logs), "-n", "512", "--save-freq", "256",
            "--verbose", "0", "-params", "n_steps:32", "n_envs:8"]
    result = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, timeout=300)
    assert result.returncode == -signal.SIGKILL, result.stderr
    run_dir = logs / "ppo" / "sbagents_GridWorld-v0_1"
    assert not list(run_dir.glob("rl_model_*_steps.zip"))
    assert list(run_dir.glob(".rl_model_*.partial"))  # what was being written stays under its temporary name
    ev = cli("evaluate", "--algo", "ppo", "--env", "GridWorld-v0", "-f", str(logs), "--load-checkpoint", "256")
    assert ev.returncode == 2 and len(ev.stderr.strip().splitlines()) == 1, ev.stderr
    assert "no checkpoint after 256 steps" in ev.stderr


@contextlib.contextmanager
def tiny_disk(folder: Path, size: str) -> Iterator[bool]:
    """A tmpfs of ``size`` mounted on ``folder`` when this process may mount one (root); yields whether it did."""
    folder.mkdir()
    if os.geteuid() != 0:
        yield False
        return
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                             capture_output=True).returncode == 0
    try:
        yield mounted
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def test_training_onto_a_full_disk(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    """The model does not fit: one line naming the model file, exit 2, and no zip that looks complete but is not.
    On a real 256 KB tmpfs where the test may mount one, else with a writer that fails as a full disk does."""
    args = ["--algo", "ppo", "--env", "GridWorld-v0", "-n", "64", "--eval-freq", "-1", "--verbose", "0",
            "--final-eval-episodes", "0", "-params", "n_steps:64", "n_envs:1", "batch_size:64",
            "policy_kwargs:{net_arch: [256, 256]}"]
    with tiny_disk(tmp_path / "disk", "256k") as mounted:
        logs = tmp_path / "disk" / "logs"
        if mounted:
            result = cli("train", *args, "-f", str(logs))
            code, err = result.returncode, result.stderr
        else:
            import sbagents.atomic as atomic

            def full(path: Path) -> None:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

            monkeypatch.setattr(atomic, "_fsync", full)
            code = run_main("train", *args, "-f", str(logs))
            err = capsys.readouterr().err
        assert code == 2, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in err, err
        assert "No space left on device" in lines[0] and ".zip" in lines[0], lines[0]
        for model in logs.rglob("*.zip"):
            read_model_data(model)  # every zip there is complete
