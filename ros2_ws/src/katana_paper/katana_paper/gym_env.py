"""The abstract blocks world of section 3.1 as a Gymnasium environment.

`import katana_paper` registers it as "katana_paper/BlocksWorld-v0". One step is one
experiment: the action picks an instance of the current setting (a height to place on and an
action's feature vector), the world executes it, and the label (+1 stable, -1 fell) comes back in
`info["label"]`. There is no task reward (the reward is 0): curiosity is the agent's business, so
a user who wants one wraps the environment (e.g. gymnasium.wrappers.TransformReward).

Observation (a Dict):
- "available": MultiBinary(n_blocks), 1 where height h (0 = the table) can be placed on now;
- "features": (n_blocks * n_actions, n_actions + 1) in [0, 1]: row i is the feature vector of
  instance i = (height i // n_actions, action i % n_actions), zero where the height is not
  available (one-hot action plus bias, the paper's features).
Action: Discrete(n_blocks * n_actions), the instance. Choosing an unavailable one changes nothing
and reports info["valid"] False and label 0; info["action_mask"] marks the valid instances.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from katana_curiosity.core.abstract_world import AbstractBlocksWorld

ENV_ID = "katana_paper/BlocksWorld-v0"


class BlocksWorldEnv(gym.Env):
    """AbstractBlocksWorld behind the Gymnasium API; seeded by reset(seed=...)."""

    metadata = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self, n_blocks: int = 8, n_features: int = 21, render_mode: str | None = None
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'ansi', got {render_mode!r}")
        self.render_mode = render_mode
        self.world = AbstractBlocksWorld(n_blocks, n_features, seed=0)  # validates the sizes
        self.n_blocks, self.n_actions = n_blocks, n_features
        self._features = self.world.features
        n_instances = n_blocks * n_features
        self.observation_space = spaces.Dict(
            {
                "available": spaces.MultiBinary(n_blocks),
                "features": spaces.Box(0.0, 1.0, (n_instances, n_features + 1), dtype=np.float64),
            }
        )
        self.action_space = spaces.Discrete(n_instances)
        self._available = np.zeros(n_blocks, dtype=np.int8)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """A new world (true models and event stream) drawn from the environment's generator."""
        super().reset(seed=seed)
        world_seed = int(self.np_random.integers(2**63))
        self.world = AbstractBlocksWorld(self.n_blocks, self.n_actions, seed=world_seed)
        return self._observe(), self._info(None, None, 0, True)

    def step(self, action: int) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if not self.action_space.contains(action):
            raise ValueError(f"action must be an instance index in [0, {self.action_space.n})")
        state, feature = divmod(int(action), self.n_actions)
        valid = bool(self._available[state])
        label = self.world.execute(state, feature) if valid else 0
        observation = self._observe()  # the new setting, which info's action mask describes
        return observation, 0.0, False, False, self._info(state, feature, label, valid)

    def render(self) -> str | None:
        if self.render_mode != "ansi":
            return None
        stacks = " | ".join(" ".join(str(j) for j in s) for s in self.world.stacks())
        return f"stacks (bottom first): {stacks}; q = {self.world.q.tolist()}"

    # -- helpers -----------------------------------------------------------------------------

    def _observe(self) -> dict[str, np.ndarray]:
        self._available[:] = 0
        self._available[self.world.available_states()] = 1
        features = np.zeros(self.observation_space["features"].shape)
        for h in np.flatnonzero(self._available):
            features[h * self.n_actions : (h + 1) * self.n_actions] = self._features
        return {"available": self._available.copy(), "features": features}

    def action_mask(self) -> np.ndarray:
        """1 for every instance of the current setting (for Discrete.sample(mask=...))."""
        return np.repeat(self._available, self.n_actions).astype(np.int8)

    def _info(self, state: int | None, feature: int | None, label: int, valid: bool) -> dict:
        return {
            "label": int(label),
            "valid": bool(valid),
            "state": state,
            "action": feature,
            "action_mask": self.action_mask(),
        }


def register() -> None:
    """Register ENV_ID with Gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(
            id=ENV_ID,
            entry_point="katana_paper.gym_env:BlocksWorldEnv",
            max_episode_steps=10_000,  # the paper's run length
        )
