"""The abstract world as a Gymnasium environment."""

import warnings

import gymnasium
import katana_paper  # noqa: F401  (registers the environment)
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from katana_curiosity.core.abstract_world import AbstractBlocksWorld
from katana_paper.gym_env import ENV_ID, BlocksWorldEnv


def test_registered_environment_passes_the_gymnasium_checker() -> None:
    env = gymnasium.make(ENV_ID)
    assert isinstance(env.unwrapped, BlocksWorldEnv)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test
        check_env(env.unwrapped, skip_render_check=True)
    env.close()


def _episode(seed: int, steps: int = 300):
    env = gymnasium.make(ENV_ID)
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    labels = []
    for _ in range(steps):
        action = env.action_space.sample(mask=info["action_mask"])
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward == 0.0 and not terminated and not truncated
        assert info["valid"] and info["label"] in (-1, 1)
        labels.append((info["state"], info["action"], info["label"]))
    return labels, obs


def test_seeded_episodes_repeat_and_differ_between_seeds() -> None:
    a, obs_a = _episode(3)
    b, obs_b = _episode(3)
    assert a == b and np.array_equal(obs_a["available"], obs_b["available"])
    c, _ = _episode(4)
    assert a != c


def test_observation_lists_the_worlds_setting_and_labels_follow_its_model() -> None:
    env = BlocksWorldEnv()
    obs, info = env.reset(seed=11)
    world = env.world
    assert isinstance(world, AbstractBlocksWorld)
    n_actions = env.n_actions
    for _ in range(200):
        available = world.available_states()
        assert np.flatnonzero(obs["available"]).tolist() == available
        rows = obs["features"].reshape(env.n_blocks, n_actions, n_actions + 1)
        for h in range(env.n_blocks):
            expected = world.features if h in available else np.zeros_like(world.features)
            np.testing.assert_array_equal(rows[h], expected)
        assert info["action_mask"].tolist() == np.repeat(obs["available"], n_actions).tolist()
        valid = np.flatnonzero(info["action_mask"])
        action = int(valid[-1])  # the highest height, its most stable feature
        obs, _, _, _, info = env.step(action)
        assert (info["state"], info["action"]) == divmod(action, n_actions)
        if info["state"] == 0:
            assert info["label"] == 1, "the table is always stable"


def test_an_instance_of_an_unavailable_height_changes_nothing() -> None:
    env = BlocksWorldEnv()
    obs, info = env.reset(seed=0)
    before = env.world.q.copy()
    blocked = int(np.flatnonzero(info["action_mask"] == 0)[0])
    obs2, reward, terminated, truncated, info2 = env.step(blocked)
    assert not info2["valid"] and info2["label"] == 0
    assert np.array_equal(env.world.q, before)
    assert np.array_equal(obs2["available"], obs["available"])
    with pytest.raises(ValueError, match="instance index"):
        env.step(env.action_space.n)


def test_readme_random_agent_runs() -> None:
    env = gymnasium.make("katana_paper/BlocksWorld-v0")
    obs, info = env.reset(seed=0)
    for _ in range(100):
        obs, reward, terminated, truncated, info = env.step(
            env.action_space.sample(mask=info["action_mask"])
        )
    assert env.unwrapped.world.settings == 100


def test_invalid_sizes_and_render_mode_are_rejected() -> None:
    with pytest.raises(ValueError, match="n_blocks"):
        BlocksWorldEnv(n_blocks=1)
    with pytest.raises(ValueError, match="render_mode"):
        BlocksWorldEnv(render_mode="human")
    env = BlocksWorldEnv(render_mode="ansi")
    env.reset(seed=0)
    assert "stacks" in env.render()
