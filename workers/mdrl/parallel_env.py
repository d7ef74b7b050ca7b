"""A PettingZoo ``ParallelEnv`` view of ONE target-localization environment.

For interoperability (other MARL libraries, the API test); training uses the batched
``TargetLocalizationEnv`` directly, which is far faster (see benchmarks/env_throughput.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from .env import TargetLocalizationEnv
from .observations import ObservationSpec, make_observer
from .spec import EnvSpec


class TargetLocalizationParallelEnv(ParallelEnv):
    """Agents ``agent_0 .. agent_{N-1}``; observation = {"observation": maps, "action_mask": int8}.

    The observation is the agent's actor input of the chosen observation kind (ODMTL by default);
    for CMTL every agent sees the joint maps. Rewards are the team reward, equal for all agents.
    """

    metadata = {"name": "target_localization_v0", "render_modes": ["ansi"]}

    def __init__(
        self,
        spec: EnvSpec | None = None,
        obs_spec: ObservationSpec | None = None,
        render_mode: str | None = None,
    ) -> None:
        self.spec = spec or EnvSpec()
        self.obs_spec = obs_spec or ObservationSpec("odmtl")
        if render_mode not in (None, "ansi"):
            raise ValueError(f"render_mode must be None or 'ansi', got {render_mode!r}")
        self.render_mode = render_mode
        self.observer = make_observer(self.spec, self.obs_spec)
        self.possible_agents = [f"agent_{i}" for i in range(self.spec.agents)]
        self.agents: list[str] = []
        self._env: TargetLocalizationEnv | None = None
        obs_space = spaces.Dict(
            {
                "observation": spaces.Box(0.0, 1.0, self.observer.actor_shape, dtype=np.float32),
                "action_mask": spaces.Box(0, 1, (self.spec.num_actions,), dtype=np.int8),
            }
        )
        act_space = spaces.Discrete(self.spec.num_actions)
        self._obs_spaces = {a: obs_space for a in self.possible_agents}
        self._act_spaces = {a: act_space for a in self.possible_agents}

    def observation_space(self, agent: str) -> spaces.Space:
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self._act_spaces[agent]

    def _observations(self) -> dict[str, dict[str, np.ndarray]]:
        actor, _ = self.observer.observe(self._env)
        mask = self._env.action_mask()[0].astype(np.int8)
        obs = {}
        for i, agent in enumerate(self.agents):
            maps = actor[0, 0 if self.observer.joint_actions else i]
            obs[agent] = {"observation": np.clip(maps, 0.0, 1.0), "action_mask": mask[i].copy()}
        return obs

    def reset(self, seed: int | None = None, options: dict | None = None):
        if self._env is None:
            self._env = TargetLocalizationEnv(self.spec, 1, seed=seed, autoreset=False)
        else:
            self._env.reset(seed=seed)
        self.agents = list(self.possible_agents)
        infos = {a: {} for a in self.agents}
        return self._observations(), infos

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called after the episode ended; call reset()")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"missing actions for {missing}")
        joint = np.array([[int(actions[a]) for a in self.agents]], dtype=np.int64)
        result = self._env.step(joint)
        terminated, truncated = bool(result.terminated[0]), bool(result.truncated[0])
        obs = self._observations()
        reward = float(result.reward[0])
        rewards = {a: reward for a in self.agents}
        terms = {a: terminated for a in self.agents}
        truncs = {a: truncated for a in self.agents}
        infos: dict[str, dict] = {a: {} for a in self.agents}
        if terminated or truncated:
            stats = result.episode
            for a in self.agents:
                infos[a] = {
                    "found": bool(stats.found[0]),
                    "length": int(stats.length[0]),
                    "cost": int(stats.cost[0]),
                }
            self.agents = []
        if self.render_mode == "ansi":
            print(self.render())
        return obs, rewards, terms, truncs, infos

    def render(self) -> str:
        """The grid as text: T target, # wall, digits agents, . free."""
        env, spec = self._env, self.spec
        if env is None:
            return ""
        grid = np.full(spec.num_cells, ".", dtype="<U1")
        grid[env.walls[0]] = "#"
        grid[env.target[0]] = "T"
        for i, p in enumerate(env.pos[0]):
            grid[p] = str(i % 10)
        return "\n".join("".join(row) for row in grid.reshape(spec.rows, spec.cols))

    def close(self) -> None:
        self._env = None
