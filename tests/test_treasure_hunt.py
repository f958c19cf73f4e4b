"""Rules of CooperativeTreasureHunt, transition by transition, plus PettingZoo's own API checks."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    render_test,
    seed_test,
)

from sbagents.envs import treasure_hunt_v0
from sbagents.envs.treasure_hunt import DEFAULT_OBSTACLES, CooperativeTreasureHunt

UP, DOWN, LEFT, RIGHT, STAY = range(5)
A0, A1, A2 = "agent_0", "agent_1", "agent_2"
# Agents far from everything, treasures in a corner row: a hand-built state used by most tests.
AGENTS = [(0, 0), (9, 9), (9, 0)]
TREASURES = [(0, 1), (1, 0), (0, 9), (5, 0), (9, 5)]


def make(**kw: object) -> CooperativeTreasureHunt:
    env = treasure_hunt_v0.parallel_env(**kw)
    env.reset(seed=0, options={"agents": AGENTS, "treasures": TREASURES})
    return env


def step(env: CooperativeTreasureHunt, a0: int = STAY, a1: int = STAY, a2: int = STAY):
    return env.step({A0: a0, A1: a1, A2: a2})


def test_spaces_and_metadata() -> None:
    env = treasure_hunt_v0.parallel_env()
    assert env.possible_agents == [A0, A1, A2]
    assert env.metadata["name"] == "treasure_hunt_v0"
    assert set(env.metadata["render_modes"]) == {"human", "ansi", "rgb_array"}
    assert env.observation_space(A0).shape == (32,)  # book: 2 + 2*5 + 2*10
    assert env.action_space(A1).n == 5
    assert len(env.obs_names) == 32 and env.action_names == ("move",)
    assert env.obstacles == DEFAULT_OBSTACLES


def test_off_grid_costs_one_and_stays() -> None:
    env = make()
    _, rew, term, trunc, infos = step(env, a0=UP, a1=RIGHT, a2=LEFT)
    assert rew == {A0: -1.0, A1: -1.0, A2: -1.0}
    assert env.positions == AGENTS
    assert infos[A0]["event"] == "wall" and not term[A0] and not trunc[A0]


def test_obstacle_costs_five_and_stays() -> None:
    env = treasure_hunt_v0.parallel_env()
    env.reset(options={"agents": [(2, 1), (1, 2), (9, 9)], "treasures": TREASURES})
    _, rew, _, _, infos = step(env, a0=RIGHT, a1=DOWN, a2=STAY)
    assert rew == {A0: -5.0, A1: -5.0, A2: -1.0}
    assert env.positions == [(2, 1), (1, 2), (9, 9)]
    assert infos[A0]["event"] == infos[A1]["event"] == "obstacle"


def test_move_and_stay_cost_one() -> None:
    env = make()
    _, rew, _, _, infos = step(env, a0=STAY, a1=UP, a2=RIGHT)
    assert rew == {A0: -1.0, A1: -1.0, A2: -1.0}
    assert env.positions == [(0, 0), (8, 9), (9, 1)]
    assert infos[A1]["treasures_collected"] == 0


def test_shared_treasure_rewards_every_agent() -> None:
    env = make()
    obs, rew, _, _, infos = step(env, a0=RIGHT)  # agent_0 onto (0, 1)
    assert rew == {A0: 9.0, A1: 9.0, A2: 9.0}
    assert infos[A2]["treasures_collected"] == 1
    assert env.present == [False, True, True, True, True]
    assert obs[A0].shape == (32,)  # fixed size after a collection
    assert obs[A0][2:4].tolist() == [-1.0, -1.0]  # collected treasure marked with the sentinel
    _, rew, _, _, _ = step(env, a0=LEFT)  # back to (0, 0): nothing left at (0, 1)
    assert rew[A0] == -1.0


def test_two_treasures_in_one_step_and_move_order() -> None:
    env = treasure_hunt_v0.parallel_env()
    # agent_0 and agent_1 both step onto (0, 1); agent_0 moves first and collects; agent_2 collects (5, 0).
    env.reset(options={"agents": [(0, 0), (0, 2), (4, 0)], "treasures": TREASURES})
    _, rew, _, _, infos = step(env, a0=RIGHT, a1=LEFT, a2=DOWN)
    assert rew == {A0: 19.0, A1: 19.0, A2: 19.0}
    assert infos[A0]["event"] == "treasure" and infos[A1]["event"] == "move"
    assert env.positions[0] == env.positions[1] == (0, 1)  # agents may share a cell


def test_individual_mode_rewards_only_collector() -> None:
    env = make(reward_mode="individual")
    _, rew, _, _, _ = step(env, a0=RIGHT)
    assert rew == {A0: 9.0, A1: -1.0, A2: -1.0}


def test_termination_when_all_collected() -> None:
    env = treasure_hunt_v0.parallel_env(n_treasures=2)
    env.reset(options={"agents": AGENTS, "treasures": [(0, 1), (9, 8)]})
    _, rew, term, trunc, infos = step(env, a0=RIGHT, a1=LEFT)
    assert rew[A2] == 19.0
    assert all(term.values()) and not any(trunc.values())
    assert all(info["is_success"] for info in infos.values())
    assert infos[A0]["treasures_collected"] == 2
    assert env.agents == []
    with pytest.raises(ValueError, match="reset"):
        step(env)


def test_truncation_at_max_cycles() -> None:
    env = make(max_cycles=5)
    for t in range(5):
        _, _, term, trunc, infos = step(env)
        assert not any(term.values())
        assert all(trunc.values()) == (t == 4)
    assert infos[A0]["is_success"] is False and infos[A0]["treasures_collected"] == 0
    assert env.agents == []


def test_egocentric_observation() -> None:
    env = treasure_hunt_v0.parallel_env(observation="egocentric")
    obs, _ = env.reset(options={"agents": AGENTS, "treasures": TREASURES})
    names = env.obs_names
    assert obs[A0].shape == env.observation_space(A0).shape == (len(names),)
    o = dict(zip(names, obs[A1].tolist(), strict=True))
    assert (o["id_0"], o["id_1"], o["id_2"]) == (0.0, 1.0, 0.0)
    assert (o["row"], o["col"], o["time_left"]) == (1.0, 1.0, 1.0)
    # nearest treasure of agent_1 at (9, 9) is (9, 5): offset (0, -4) / 9
    assert o["near0_present"] == 1.0 and o["near0_drow"] == 0.0
    assert o["near0_dcol"] == pytest.approx(-4 / 9)
    assert o["other0_drow"] == pytest.approx(-1.0) and o["other1_dcol"] == pytest.approx(-1.0)
    assert (o["blocked_up"], o["blocked_down"], o["blocked_left"], o["blocked_right"]) == (0.0, 1.0, 0.0, 1.0)
    obs, *_ = step(env, a0=RIGHT)  # collect (0, 1): the last treasure slot becomes empty, size unchanged
    o = dict(zip(names, obs[A1].tolist(), strict=True))
    assert o["near4_present"] == 0.0 and o["near3_present"] == 1.0
    assert o["time_left"] == pytest.approx(1 - 1 / 50)
    assert all(env.observation_space(a).contains(obs[a]) for a in env.possible_agents)


def test_random_starts_are_distinct_free_and_seeded() -> None:
    env = treasure_hunt_v0.parallel_env()
    env.reset(seed=3)
    first = (list(env.positions), list(env.treasures))
    cells = env.positions + env.treasures
    assert len(set(cells)) == 8 and not set(cells) & set(DEFAULT_OBSTACLES)
    env.reset(seed=3)
    assert (env.positions, env.treasures) == first


def test_bad_actions_name_the_agent() -> None:
    env = make()
    with pytest.raises(ValueError, match="agent_7"):
        env.step({A0: 0, A1: 0, A2: 0, "agent_7": 0})
    with pytest.raises(ValueError, match="agent_2"):
        env.step({A0: 0, A1: 0})
    with pytest.raises(ValueError, match="agent_1"):
        env.step({A0: 0, A1: 5, A2: 0})


def test_unknown_kwargs_list_accepted_keys() -> None:
    with pytest.raises(TypeError, match="grid_size.*n_agents"):
        treasure_hunt_v0.parallel_env(gridsize=5)
    with pytest.raises(TypeError, match="accepted"):
        treasure_hunt_v0.env(foo=1)
    with pytest.raises(ValueError, match="reward_mode"):
        treasure_hunt_v0.parallel_env(reward_mode="selfish")


def test_render_modes() -> None:
    env = treasure_hunt_v0.parallel_env(render_mode="ansi")
    env.reset(options={"agents": AGENTS, "treasures": TREASURES})
    lines = env.render().split("\n")
    assert lines[0].split() == ["A0", "T", ".", ".", ".", ".", ".", ".", ".", "T"]
    assert lines[2].split()[2] == "X"
    env = treasure_hunt_v0.parallel_env(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (320, 320, 3) and frame.dtype == np.uint8


@pytest.mark.parametrize("observation", ["book", "egocentric"])
def test_pettingzoo_api(observation: str) -> None:
    parallel_api_test(treasure_hunt_v0.parallel_env(observation=observation), num_cycles=300)
    api_test(treasure_hunt_v0.env(observation=observation), num_cycles=300)
    parallel_seed_test(lambda: treasure_hunt_v0.parallel_env(observation=observation))
    seed_test(lambda: treasure_hunt_v0.env(observation=observation))


def test_pettingzoo_render_and_max_cycles() -> None:
    render_test(treasure_hunt_v0.env)
    max_cycles_test(treasure_hunt_v0)


def test_larger_variant() -> None:
    env = treasure_hunt_v0.parallel_env(grid_size=15, n_agents=5, n_treasures=8, observation="egocentric")
    obs, _ = env.reset(seed=1)
    assert len(obs) == 5 and obs["agent_4"].shape == (5 + 3 + 3 * 8 + 2 * 4 + 4,)
