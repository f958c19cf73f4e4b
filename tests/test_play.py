"""``python -m sbagents.play`` and :mod:`sbagents.games.terminal`: a person against a trained agent in the terminal.

The text forms are checked on positions of the real PettingZoo envs (tic-tac-toe cell numbers against pettingzoo's
own picture); the CLI is driven through stdin with tiny runs trained in-process.
"""

from __future__ import annotations

import io
import os
import re
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_helpers import REPO, check_error, cli, run_main
from pettingzoo.classic import connect_four_v3, leduc_holdem_v4, texas_holdem_v4, tictactoe_v3

from sbagents.games.terminal import (
    QuitSession,
    accepted_moves,
    chips_per_point,
    describe_action,
    game_kind,
    outcome_line,
    parse_move,
    play_game,
    render_board,
    tally_line,
    ttt_action,
    ttt_cell,
)

TTT, C4 = "pettingzoo.classic.tictactoe_v3", "pettingzoo.classic.connect_four_v3"
HOLDEM = "pettingzoo.classic.texas_holdem_v4"
TINY = ["--eval-freq", "0", "--final-eval-episodes", "0", "--verbose", "0", "--seed", "0"]


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A log folder with tiny ppo_mask runs of tic-tac-toe, connect four and hold'em, and a GridWorld run."""
    folder = tmp_path_factory.mktemp("play_logs")
    small = ["-params", "n_envs:2", "n_steps:128", "batch_size:128", "n_epochs:1"]
    for env in (TTT, C4, HOLDEM):
        assert run_main("train", "--algo", "ppo_mask", "--env", env, "-n", "512", "-f", str(folder), *TINY, *small) == 0
    assert run_main("train", "--algo", "qlearning", "-n", "100", "-f", str(folder), *TINY) == 0
    return folder


def play(logs: Path, env: str, stdin: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python -m sbagents.play`` (in this process) on the run of ``env`` with ``stdin`` as the human's entries
    (piped, not a terminal: play echoes them)."""
    saved = sys.stdin
    sys.stdin = io.StringIO(stdin)
    try:
        return cli("play", "--algo", "ppo_mask", "--env", env, "-f", str(logs), *args, cwd=REPO)
    finally:
        sys.stdin = saved


def position(make_env: Callable[[], Any], moves: Sequence[int], seed: int = 0) -> tuple[Any, str, np.ndarray]:
    """A fresh env after ``moves``: (env, agent to move, its action mask)."""
    env = make_env()
    env.reset(seed=seed)
    for move in moves:
        env.step(move)
    agent = env.agent_selection
    return env, agent, np.asarray(env.observe(agent)["action_mask"])


def grid(board: str) -> list[list[str]]:
    """The 3x3 marks/numbers of a drawn tic-tac-toe board."""
    lines = [line for line in board.splitlines() if "|" in line]
    return [[cell.strip() for cell in line.split("|")] for line in lines]


# --------------------------------------------------------------------------------------------------------------------
# Text forms on the real envs
# --------------------------------------------------------------------------------------------------------------------


def test_tictactoe_cells_match_pettingzoo_picture() -> None:
    """Cell n (reading order of the picture pettingzoo renders) is the action pettingzoo draws there."""
    assert sorted(ttt_cell(a) for a in range(9)) == list(range(1, 10))
    for action in range(9):
        env = tictactoe_v3.env(render_mode="rgb_array", screen_height=90)
        env.reset()
        before = env.render().astype(int)
        env.step(action)
        changed = np.abs(env.render().astype(int) - before).sum(-1) > 0
        rows, cols = np.nonzero(changed)
        row, col = int(rows.mean() * 3 // changed.shape[0]), int(cols.mean() * 3 // changed.shape[1])
        cell = 3 * row + col + 1
        assert (row, col) == (action % 3, action // 3) and ttt_cell(action) == cell and ttt_action(cell) == action
        assert describe_action("tictactoe_v3", action) == f"cell {cell}"
        mask = np.ones(9, np.int8)
        assert parse_move("tictactoe_v3", f" {cell} ", mask) == action
        first, second = env.possible_agents
        assert grid(render_board("tictactoe_v3", env, first))[row][col] == "X"  # the mover's mark, where drawn
        assert grid(render_board("tictactoe_v3", env, second))[row][col] == "O"
        free = [c for r in grid(render_board("tictactoe", env, second)) for c in r if c not in ("X", "O")]
        assert free == [str(n) for n in range(1, 10) if n != cell]


def test_tictactoe_parse_errors() -> None:
    env, agent, mask = position(tictactoe_v3.env, [ttt_action(5), ttt_action(1)])
    assert parse_move("tictactoe_v3", "9", mask) == 8
    for entry, problem in [("5", "cell 5 is taken"), ("1", "cell 1 is taken"), ("0", "there is no cell 0"),
                           ("10", "there is no cell 10"), ("x", "'x' is not a cell"), ("", "no move entered")]:
        with pytest.raises(ValueError, match="enter a free cell 1-9: 2, 3, 4, 6, 7, 8, 9$") as info:
            parse_move("tictactoe_v3", entry, mask)
        assert str(info.value).startswith(problem)


def test_connect_four_board_and_full_column() -> None:
    env, agent, mask = position(connect_four_v3.env, [2] * 6 + [3])
    assert agent == "player_1" and mask.tolist() == [1, 1, 0, 1, 1, 1, 1]
    board = render_board("connect_four_v3", env, agent).splitlines()
    assert board[7] == "  1 2 3 4 5 6 7" and board[6].startswith("+")
    cells = [line[2:-2].split(" ") for line in board[:6]]
    assert [row[2] for row in cells] == ["X", "O", "X", "O", "X", "O"]  # column 3 full, top row first: O = player_0
    assert cells[5][3] == "O" and sum(row.count(".") for row in cells) == 42 - 7
    mine = [line[2:-2].split(" ") for line in render_board("connect_four", env, "player_0").splitlines()[:6]]
    assert [row[2] for row in mine] == ["O", "X", "O", "X", "O", "X"] and mine[5][3] == "X"
    with pytest.raises(ValueError, match=r"^column 3 is full; enter a column 1-7 that is not full: 1, 2, 4, 5, 6, 7$"):
        parse_move("connect_four_v3", "3", mask)
    for entry in ("8", "0", "four", "4.5"):
        with pytest.raises(ValueError, match="enter a column 1-7 that is not full"):
            parse_move("connect_four_v3", entry, mask)
    assert parse_move("connect_four_v3", "4", mask) == 3 and describe_action("connect_four_v3", 3) == "column 4"
    assert game_kind("connect_four_v3") == "connect_four"


def test_holdem_text() -> None:
    env, agent, mask = position(texas_holdem_v4.env, [], seed=3)
    game = env.unwrapped.env.game
    me = env.possible_agents.index(agent)
    board = render_board("texas_holdem_v4", env, agent)
    hand = " ".join(f"{c.get_index()[1:]}{c.get_index()[0].lower()}" for c in game.players[me].hand)
    assert f"your hand:  {hand}" in board and "board:      -" in board and board.startswith("pre-flop: pot 3")
    legal = [("call", "raise", "fold", "check")[a] for a in np.flatnonzero(mask)]
    assert legal == ["call", "raise", "fold"]
    assert "legal: call (0), raise (1), fold (2)" in board
    assert parse_move("texas_holdem_v4", "Raise", mask) == 1 and parse_move("texas_holdem_v4", "2", mask) == 2
    with pytest.raises(ValueError, match=r"^check is not allowed now; enter one of call \(0\), raise \(1\), fold"):
        parse_move("texas_holdem_v4", "check", mask)
    with pytest.raises(ValueError, match=r"^there is no action 4; enter one of call \(0\)"):
        parse_move("texas_holdem_v4", "4", mask)
    assert [describe_action("texas_holdem_v4", a) for a in range(4)] == ["call", "raise", "fold", "check"]
    assert chips_per_point("texas_holdem_v4", env) == 2.0 and chips_per_point("tictactoe_v3", env) is None
    env.step(2)  # fold: the hand is over, the folded hand is not shown
    assert "'s hand" not in render_board("texas_holdem_v4", env, agent) and "legal" not in render_board(
        "texas_holdem_v4", env, agent)
    assert env.rewards[agent] == -0.5 and outcome_line(-0.5, 2.0) == "result: you lose 1 chip"


def test_generic_fallback() -> None:
    env, agent, mask = position(leduc_holdem_v4.env, [])
    assert game_kind("leduc_holdem_v4") == "generic"
    board = render_board("leduc_holdem_v4", env, agent)
    legal = np.flatnonzero(mask).tolist()
    assert board.startswith("observation (36,): [") and f"legal actions: {', '.join(map(str, legal))}" in board
    assert parse_move("leduc_holdem_v4", str(legal[-1]), mask) == legal[-1]
    illegal = int(np.flatnonzero(mask == 0)[0])
    with pytest.raises(ValueError, match=f"^action {illegal} is not allowed now; enter a legal action index: "):
        parse_move("leduc_holdem_v4", str(illegal), mask)
    assert describe_action("leduc_holdem_v4", 2) == "action 2"
    assert accepted_moves("leduc_holdem_v4", mask) == f"enter a legal action index: {', '.join(map(str, legal))}"


def test_outcome_and_tally_lines() -> None:
    assert [outcome_line(r) for r in (1, 0, -1)] == ["result: you win (+1)", "result: draw (+0)",
                                                       "result: you lose (-1)"]
    assert outcome_line(1.5, 2.0) == "result: you win 3 chips" and "split pot" in outcome_line(0.0, 2.0)
    assert tally_line([1, 0, -1, 1]) == "tally: 2 wins, 1 draw, 1 loss in 4 games"
    assert tally_line([]) == "tally: 0 wins, 0 draws, 0 losses in 0 games"
    assert tally_line([1.5, -0.5], 2.0) == "tally: 1 win, 0 draws, 1 loss in 2 hands; chips won: +2"


def test_play_game_loop() -> None:
    """A whole game through :func:`play_game`: bad entries re-asked, returns summed, ``q`` quits."""
    entries: Iterator[str] = iter(["oops", "5", "5", *[str(n) for n in range(1, 10)] * 2])
    said: list[str] = []
    env = tictactoe_v3.env()
    returns = play_game(env, "tictactoe_v3", "player_1", lambda obs, mask: int(np.flatnonzero(mask)[0]),
                        lambda prompt: next(entries), said.append)
    assert set(returns) == {"player_1", "player_2"} and returns["player_1"] == -returns["player_2"]
    assert said[1].startswith("'oops' is not a cell") and said[2] == "you play cell 5"
    assert any(line.startswith("cell 5 is taken") for line in said)
    assert said[-1].count("X") + said[-1].count("O") >= 5 + 2  # the final board (the legend has an X and an O)
    with pytest.raises(QuitSession):
        play_game(env, "tictactoe_v3", "player_1", lambda obs, mask: 0, lambda prompt: "quit", said.append)


# --------------------------------------------------------------------------------------------------------------------
# The CLI
# --------------------------------------------------------------------------------------------------------------------


def test_play_tictactoe_session(logs: Path) -> None:
    entries = ["x", "0", "10", "5", "5", *[str(n) for n in range(1, 10)] * 3]
    result = play(logs, TTT, "\n".join(entries) + "\n", "--seat", "first")
    out = result.stdout
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert " 1 | 2 | 3\n---+---+---\n 4 | 5 | 6\n---+---+---\n 7 | 8 | 9" in out  # the empty board, human first
    assert "'x' is not a cell; enter a free cell 1-9: 1, 2, 3, 4, 5, 6, 7, 8, 9" in out
    assert "there is no cell 0; enter a free cell" in out and "there is no cell 10; enter a free cell" in out
    assert re.search(r"cell 5 is taken; enter a free cell 1-9: (\d, )*\d\n", out)
    assert out.index("there is no cell 10") < out.index("you play cell 5") < out.index("cell 5 is taken")
    ours, theirs = out.count("you play cell"), out.count("agent plays cell")
    assert 3 <= ours <= 5 and ours - 1 <= theirs <= ours and ours + theirs >= 5
    lines = out.splitlines()
    assert lines[-2] in ("result: you win (+1)", "result: draw (+0)", "result: you lose (-1)")
    expected = {"result: you win (+1)": "1 win, 0 draws, 0 losses", "result: draw (+0)": "0 wins, 1 draw, 0 losses",
                "result: you lose (-1)": "0 wins, 0 draws, 1 loss"}[lines[-2]]
    assert lines[-1] == f"tally: {expected} in 1 game"
    final = grid("\n".join(lines[-8:-2]))  # the board drawn at the end, before the result and the tally
    assert sum(row.count("X") for row in final) == ours and sum(row.count("O") for row in final) == theirs


def test_play_eof_mid_game(logs: Path) -> None:
    result = play(logs, TTT, "5\n", "--seat", "first", "--games", "3")
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    assert "you play cell 5" in result.stdout and "agent plays cell" in result.stdout
    assert result.stdout.rstrip().endswith("end of input\ntally: 0 wins, 0 draws, 0 losses in 0 games")


def test_play_connect_four_quit(logs: Path) -> None:
    result = play(logs, C4, "8\nx\n4\nq\n", "--seat", "second", "--stochastic", "--seed", "1")
    out = result.stdout
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    assert "game 1 of 1: you are player_1 (seat 2 of 2)" in out
    assert out.index("agent plays column") < out.index("  1 2 3 4 5 6 7")  # the agent moved first
    assert "there is no column 8; enter a column 1-7 that is not full: 1, 2, 3, 4, 5, 6, 7" in out
    assert "'x' is not a column; enter a column 1-7" in out and "you play column 4" in out
    assert out.rstrip().endswith("you quit\ntally: 0 wins, 0 draws, 0 losses in 0 games")


def test_play_holdem_hand(logs: Path) -> None:
    """Check when possible, else call: the hand ends with a result in chips."""
    result = play(logs, HOLDEM, "check\ncall\n" * 20, "--games", "1", "--seed", "0")
    out = result.stdout
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    assert "hand 1 of 1: you are player_0" in out and "your hand:  " in out and "pot " in out
    outcome = re.search(r"^result: (?:you (win|lose) (\d+) chips?|split pot.*)$", out, re.MULTILINE)
    assert outcome, out
    chips = 0 if outcome.group(1) is None else int(outcome.group(2)) * (1 if outcome.group(1) == "win" else -1)
    assert out.splitlines()[-1].endswith(f"in 1 hand; chips won: {chips:+d}")


def test_play_ctrl_c_at_the_prompt(logs: Path) -> None:
    """Ctrl-C while the human thinks: the tally so far, one line on stderr, exit 130, no traceback."""
    # a subprocess: a real SIGINT while input() waits on a pipe is the point
    command = [sys.executable, "-m", "sbagents.play", "--algo", "ppo_mask", "--env", TTT, "-f", str(logs)]
    proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.stdout is not None
    shown = b""
    while b"q quits): " not in shown:  # input() flushes its prompt
        chunk = os.read(proc.stdout.fileno(), 4096)
        if not chunk:
            break
        shown += chunk
    proc.send_signal(signal.SIGINT)
    rest, err = proc.communicate(timeout=120)
    assert b"your move (cell 1-9; q quits): " in shown, shown + err
    assert proc.returncode == 130, err
    assert err.decode().splitlines() == ["python -m sbagents.play: interrupted"]
    assert (shown + rest).decode().rstrip().endswith("tally: 0 wins, 0 draws, 0 losses in 0 games")


def test_play_refuses_non_games_and_missing_runs(logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    result = cli("play", "--algo", "qlearning", "--env", "sbagents/GridWorld-v0", "-f", str(logs), cwd=REPO)
    check_error(result.returncode, result.stderr, "sbagents/GridWorld-v0 is not a turn-based game")
    cases = [
        (["--algo", "ppo_mask", "--env", TTT, "-f", str(logs), "--exp-id", "7"], "no run tictactoe_v3_7"),
        (["--algo", "ppo_mask", "--env", TTT, "-f", str(logs / "nothing")], "no ppo_mask run for tictactoe_v3"),
        (["--algo", "ppo_mask", "--env", TTT, "-f", str(logs), "--load-best"], "no evaluation ran during training"),
        (["--algo", "ppo_mask", "--env", TTT, "-f", str(logs), "--games", "0"], "--games must be >= 1"),
        (["--algo", "ppo_mask", "--env", TTT, "-f", str(logs), "--seat", "middle"], "invalid choice: 'middle'"),
    ]
    for args, expected in cases:
        capsys.readouterr()
        code = run_main("play", *args)
        check_error(code, capsys.readouterr().err, expected)
