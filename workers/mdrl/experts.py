"""Experts for Demonstration Cloning (Alg. 4.1) and MEDC (Alg. 5.1): action rankings.

An expert only has to RANK each agent's actions from the current state (thesis 4.6.2: "the
expert ranks all possible actions from best to worst"); it never acts and is never trained.
So any saved model (any observation kind, grid size, team size or move set) can be an expert
once an adapter builds what it expects from the learner's env state.

The interface (``Expert``): ``scores(env, rows) -> float32 (k, N, A)`` for the envs ``rows``
(k of the B envs) of a ``TargetLocalizationEnv`` (or anything with its public state, see
``docs/mdrl-core.md``), over the TASK's N agents and A actions. Higher is better; only the
order among valid actions matters; ``-inf`` = "not ranked" (invalid, or an action the expert
cannot express): the selector never takes it from the expert.

Implementations:

* ``ModelExpert`` - a saved model (``modelio.load_model``) behind an adapter (below).
* ``OracleExpert`` (``oracle``) - knows the target: ranks each agent's actions by the BFS
  distance of the cell they lead to; its first choice is ``baselines.OraclePolicy``'s action.
* ``PolicyExpert`` (``bayes``, ``uniform``) - a baseline policy as a one-hot ranking (its
  action first, the other valid actions tied behind it).
* Faulty experts (thesis lines 1125-1133, issue 10 Deliver 5): ``RandomExpert`` (``random``,
  a fresh uniform random ranking of the valid actions each step), ``BiasedExpert``
  (``biased:K``, always ranks action K first), ``MaliciousExpert`` (``malicious:REF``, the
  reversed ranking of a good expert REF: its LOWEST-ranked valid action comes first - with
  the oracle that is a step away from the target, the thesis' "opposite action").

``load_expert(ref, env_spec)`` builds any of them from one string; ``load_experts`` a list.
``FollowExpert`` runs one as the whole team's policy: how a requester reviews an expert on
its own task (``drlaas eval --as-expert``).

The model adapter (``ModelExpert``), what it does and where it refuses:

* Observations: the expert gets its OWN observer (its kind, window and wall setting) built on
  the task's grid and team, and its input channels are picked BY NAME from that observer's
  channels (``Observer.actor_channels``). An expert trained with fewer agents sees each task
  agent as "its" agent and the other task agents are dropped (1-agent expert: no others map)
  or merged into its "others" map (a multi-agent expert on a larger team); an expert trained
  with more agents than the task gets an all-zero others map (there is nobody else).
* Grid size: ODMTL inputs are ``w x w`` windows and downsized maps, so an ODMTL expert works
  on any grid, smaller than its window too (the window pads off-grid cells, the downsizing
  interpolates up: ``make_observer(any_window=True)``); DMTL and CMTL inputs are full
  ``m x n`` maps, so those experts refuse another grid (``ExpertError``).
* Team size: CMTL's joint actor is over ``A**M`` joint actions of exactly M agents, so a CMTL
  expert refuses another team size; its ranking of agent i is the marginal probability of
  agent i's action under the joint policy.
* Moves: actions are matched by their (drow, dcol) step (``spec.MOVES``): a 4-move expert
  ranks idle and the 4 axis moves of an 8-move task (diagonals unranked); an 8-move expert on
  a 4-move task never proposes its diagonals. CMTL experts need the task's move set.
* Wall maps: a wall-aware expert reads the task's walls (all free if the task has none); an
  expert trained without wall maps does not see them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from workers.mdrl.baselines import BASELINES, make_baseline

FAULTY = ("random", "biased:K", "malicious:REF")
BUILTINS = ("oracle", "bayes", "uniform", *FAULTY)
"""Expert names ``load_expert`` knows besides model directories."""
NOT_RANKED = -np.inf
"""Score of an action the expert does not propose (invalid or not in its action set)."""


class ExpertError(ValueError):
    """An expert cannot be loaded or cannot serve this task (the message says which, and why)."""


class Expert(Protocol):
    """Ranks every task agent's actions (see the module docstring)."""

    name: str
    """What the model card records: a path, a CID or a built-in name."""
    every_step: bool
    """True if the expert keeps per-episode state and must see every step of every env
    (stateful baselines); the selector then calls it each step even when nobody follows it."""

    def scores(self, env: Any, rows: np.ndarray) -> np.ndarray: ...


class EnvRows:
    """A read-only view of some envs (``rows``) of a batched env: arrays whose first axis is
    the batch are indexed by ``rows``; ``past_pos`` and ``action_mask`` likewise. Lets an
    expert run on the few envs that follow it instead of all B."""

    def __init__(self, env: Any, rows: np.ndarray):
        self._env, self._rows = env, np.asarray(rows, dtype=np.int64)
        self._b = np.shape(env.pos)[0]
        self.num_envs = len(self._rows)

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._env, name)
        if isinstance(value, np.ndarray) and value.ndim and value.shape[0] == self._b:
            return value[self._rows]
        return value

    def past_pos(self, k: int) -> np.ndarray:
        return self._env.past_pos(k)[self._rows]

    def action_mask(self) -> np.ndarray:
        return self._env.action_mask()[self._rows]

    def add_unit_counts(self, *args: Any) -> None:
        """The belief filter's update for the view's envs: their walls, not the first envs'."""
        self._env.add_unit_counts(*args, walls=self.walls)

    def walking_steps(self, cells: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        return self._env.walking_steps(cells, self._rows if rows is None else self._rows[rows])


def rows_view(env: Any, rows: np.ndarray | None) -> Any:
    """``env`` itself when ``rows`` is None or all envs in order, else an ``EnvRows`` view."""
    b = np.shape(env.pos)[0]
    if rows is None or (len(rows) == b and np.array_equal(rows, np.arange(b))):
        return env
    return EnvRows(env, rows)


def _rank_valid(scores: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Scores of valid actions, ``NOT_RANKED`` elsewhere, as float32."""
    return np.where(mask, scores, NOT_RANKED).astype(np.float32)


# ---------------------------------------------------------------------------- baselines


class OracleExpert:
    """Knows the target (``env.dist``, BFS steps): a full ranking whose first choice is
    ``OraclePolicy``'s action. The agent closest to the target ranks actions by the distance
    of the cell they reach (closer first, ties to the lower index); every other agent ranks
    idle first (the oracle keeps them still), then its moves by the same distance."""

    every_step = False

    def __init__(self, name: str = "oracle"):
        self.name = name

    def scores(self, env: Any, rows: np.ndarray | None = None) -> np.ndarray:
        view = rows_view(env, rows)
        mask = np.asarray(view.action_mask())
        b, n, a = mask.shape
        dist = np.asarray(view.dist).astype(np.float64)
        idx = np.arange(b)
        nc = np.asarray(view.next_cell)[idx[:, None, None], view.pos[:, :, None], np.arange(a)]
        d_next = dist[idx[:, None, None], np.where(nc >= 0, nc, 0)]
        score = -d_next - 1e-3 * np.arange(a)  # ties: lower action index first (as the policy)
        here = dist[idx[:, None], view.pos]
        walker = np.argmin(here, axis=1)
        others = np.ones((b, n), dtype=bool)
        others[idx, walker] = False
        score[:, :, 0] = np.where(others, 1.0, score[:, :, 0])  # > every -distance: first
        return _rank_valid(score, mask & (nc >= 0))


class PolicyExpert:
    """A ``baselines`` policy (``reset(env)``, ``act(env)``) as a one-hot ranking: its action
    first, the other valid actions tied behind. Baselines keep per-episode state, so it sees
    every step of all envs (``every_step``)."""

    every_step = True

    def __init__(self, policy: Any, name: str):
        self.policy, self.name = policy, name
        self._reset = False

    def scores(self, env: Any, rows: np.ndarray | None = None) -> np.ndarray:
        if not self._reset:
            self.policy.reset(env)
            self._reset = True
        mask = np.asarray(env.action_mask())
        actions = self.policy.act(env)
        score = np.zeros(mask.shape, dtype=np.float32)
        np.put_along_axis(score, actions[..., None], 1.0, axis=-1)
        out = _rank_valid(score, mask)
        return out if rows is None else out[rows]


# ---------------------------------------------------------------------------- faulty experts


class RandomExpert:
    """Faulty: a fresh uniform random ranking of the valid actions at every call (line 1127)."""

    every_step = False

    def __init__(self, seed: int = 0, name: str = "random"):
        self.name = name
        self.rng = np.random.default_rng(seed)

    def scores(self, env: Any, rows: np.ndarray | None = None) -> np.ndarray:
        mask = np.asarray(rows_view(env, rows).action_mask())
        return _rank_valid(self.rng.random(mask.shape), mask)

    def state_dict(self) -> dict[str, Any]:
        return {"rng": self.rng.bit_generator.state}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        self.rng.bit_generator.state = d["rng"]


class BiasedExpert:
    """Faulty: always ranks action ``action`` first, whatever it sees (line 1128); the other
    valid actions are tied behind it (so when K is invalid the selector falls back to the
    lowest-index valid action above the threshold)."""

    every_step = False

    def __init__(self, action: int, num_actions: int, name: str | None = None):
        if not 0 <= action < num_actions:
            raise ExpertError(f"biased expert: action {action} is not one of the task's "
                              f"{num_actions} actions (0..{num_actions - 1})")
        self.action, self.name = int(action), name or f"biased:{action}"

    def scores(self, env: Any, rows: np.ndarray | None = None) -> np.ndarray:
        mask = np.asarray(rows_view(env, rows).action_mask())
        score = np.zeros(mask.shape)
        score[..., self.action] = 1.0
        return _rank_valid(score, mask)


class MaliciousExpert:
    """Faulty: knows the right action but proposes the worst (line 1129): the reversed ranking
    of a good expert, so its first choice is the good expert's LOWEST-ranked valid action."""

    def __init__(self, good: Any, name: str | None = None):
        self.good, self.name = good, name or f"malicious:{good.name}"
        self.every_step = bool(getattr(good, "every_step", False))

    def scores(self, env: Any, rows: np.ndarray | None = None) -> np.ndarray:
        good = self.good.scores(env, rows)
        return np.where(np.isfinite(good), -good, NOT_RANKED).astype(np.float32)

    def state_dict(self) -> dict[str, Any]:
        return self.good.state_dict() if hasattr(self.good, "state_dict") else {}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        if hasattr(self.good, "load_state_dict"):
            self.good.load_state_dict(d)


# ---------------------------------------------------------------------------- model experts


def action_map(expert_moves: int, task_moves: int) -> np.ndarray:
    """int (A_expert,): the task action with the same (drow, dcol) step as each expert action,
    -1 where the task has none (an 8-move expert's diagonals on a 4-move task)."""
    from workers.mdrl.spec import MOVES

    task = {tuple(m): i for i, m in enumerate(MOVES[task_moves].tolist())}
    return np.array([task.get(tuple(m), -1) for m in MOVES[expert_moves].tolist()], np.int64)


def expert_misfit(exp: Any, kind: str, walls_encoder: bool, task: Any) -> str | None:
    """Why an expert trained on EnvSpec ``exp`` with inputs of ``kind`` (and a walls encoder)
    cannot serve a task on EnvSpec ``task``; None when the adapter can serve it. Needs only
    the expert's card, so a worker checks it before accepting an offer."""
    grid, task_grid = (exp.rows, exp.cols), (task.rows, task.cols)
    if kind in ("dmtl", "cmtl") and grid != task_grid:
        return (f"{kind.upper()} reads full {grid[0]}x{grid[1]} maps, so it cannot serve a "
                f"{task_grid[0]}x{task_grid[1]} task (an ODMTL expert can: its inputs do not "
                "depend on the grid size)")
    if kind == "cmtl" and exp.agents != task.agents:
        return (f"a CMTL actor picks joint actions of exactly {exp.agents} agent(s); the task "
                f"has {task.agents}")
    if kind == "cmtl" and exp.moves != task.moves:
        return f"a CMTL expert needs the task's move set ({exp.moves} moves vs {task.moves})"
    if walls_encoder and grid != task_grid:
        return (f"its walls encoder reads {grid[0]}x{grid[1]} maps, so it cannot serve a "
                f"{task_grid[0]}x{task_grid[1]} task")
    try:  # what the adapter builds: the task's env, and its own agent count on that grid
        dataclasses.replace(laid_on_task(exp, task), agents=exp.agents)
    except ValueError as exc:
        return f"its env cannot be laid on the task's {task_grid[0]}x{task_grid[1]} grid: {exc}"
    return None


def laid_on_task(exp: Any, task: Any) -> Any:
    """The expert's EnvSpec ``exp`` moved onto the task's EnvSpec ``task``: the task's grid,
    walls, agents and move set, the expert's physics (what its readings are scaled by). The
    adapter's observer and the resource model's sizing both start from it."""
    return dataclasses.replace(exp, rows=task.rows, cols=task.cols, agents=task.agents,
                               walls=task.walls, wall_length=task.wall_length, moves=task.moves)


class ModelExpert:
    """A saved model ranking actions by its policy's log-probabilities, through the adapter of
    the module docstring. ``policy`` is what ``modelio.load_model`` returns (it carries
    ``card`` and ``env_spec``); ``task`` is the EnvSpec of the env the expert will see."""

    every_step = False

    def __init__(self, policy: Any, task: Any, name: str):
        from workers.mdrl.observations import channel_layout, make_observer

        self.name, self.policy = name, policy
        self.agent = policy.agent
        exp = policy.env_spec
        obs = policy.observer.obs_spec
        kind = obs.kind
        # resolve "walls = iff the env can have walls" against the EXPERT's env: its input set
        obs = dataclasses.replace(obs, walls=channel_layout(exp, obs).walls)
        what = f"expert {name!r} ({kind.upper()}, {exp.agents} agent(s), {exp.rows}x{exp.cols})"
        why = expert_misfit(exp, kind, bool(obs.walls_embedding), task)
        if why is not None:
            raise ExpertError(f"{what}: {why}")
        self.joint = kind == "cmtl"
        on_task = laid_on_task(exp, task)
        self.observer = make_observer(on_task, obs, getattr(policy.observer, "embedder", None),
                                      any_window=True)
        want = channel_layout(dataclasses.replace(on_task, agents=exp.agents), obs).actor
        have = list(self.observer.actor_channels)
        zero_ok = {"others", "ds_others"}  # no other agent in the task: an empty map is exact
        missing = [c for c in want if c not in have and c not in zero_ok]
        if missing:
            raise ExpertError(f"{what}: the task cannot provide its input channel(s) {missing}")
        self.channels = np.array([have.index(c) if c in have else -1 for c in want])
        card_obs = policy.card.get("observation")
        card_shape = card_obs.get("actor_shape") if isinstance(card_obs, dict) else None
        if not isinstance(card_shape, list):
            raise ExpertError(f"{what}: its card has no observation.actor_shape (the input "
                              "shape the adapter must build)")
        card_shape = tuple(card_shape)
        shape = (len(want), *self.observer.actor_shape[1:])
        if shape != card_shape:
            raise ExpertError(f"{what}: the adapter builds inputs of shape {shape}, the model "
                              f"expects {card_shape}")
        self.amap = action_map(exp.moves, task.moves)
        self.task_actions = task.num_actions
        from workers.mdrl.cae import tensor_digest

        self.digest = tensor_digest(self.agent.state_dict())

    def state_dict(self) -> dict[str, Any]:
        """The weights' digest: a resumed run checks that the model at the expert's path is
        still the one it learned from (the card lists the path, so a swap would go unseen)."""
        return {"digest": self.digest}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        if d.get("digest", self.digest) != self.digest:
            raise ExpertError(f"expert {self.name!r} is not the model this run learned from "
                              f"(weights {self.digest}, the checkpoint's {d['digest']}): put "
                              "the original back or start a new run")

    @torch.inference_mode()
    def scores(self, env: Any, rows: np.ndarray | None = None) -> np.ndarray:
        from workers.mdrl.observations import joint_mask
        from workers.mdrl.ppo import masked_log_probs

        view = rows_view(env, rows)
        actor, _ = self.observer.observe(view)  # (k, N or 1, C, H, W)
        mask = np.asarray(view.action_mask())  # (k, N, A_task)
        k, n = mask.shape[:2]
        if self.channels.min() < 0:  # an others map the task cannot have: zeros
            pad = np.concatenate([actor, np.zeros_like(actor[:, :, :1])], axis=2)
            actor = pad[:, :, self.channels]
        else:
            actor = actor[:, :, self.channels]
        ok = self.amap >= 0
        emask = np.zeros((k, n, len(self.amap)), dtype=bool)  # (k, N, A_expert)
        emask[:, :, ok] = mask[:, :, self.amap[ok]]
        if self.joint:
            jm = torch.from_numpy(joint_mask(emask))
            logits = self.agent.logits(torch.from_numpy(actor[:, 0]), jm)
            probs = masked_log_probs(logits, jm).exp().reshape(k, *([len(self.amap)] * n))
            axes = range(1, n + 1)
            elogp = np.stack([probs.sum(dim=tuple(a for a in axes if a != i)).numpy()
                              for i in axes], axis=1)  # marginal of each agent's action
            elogp = np.log(np.maximum(elogp, 1e-30))
        else:
            flat = torch.from_numpy(emask.reshape(k * n, -1))
            obs = torch.from_numpy(np.ascontiguousarray(actor)).reshape(k * n, *actor.shape[2:])
            elogp = masked_log_probs(self.agent.logits(obs, flat), flat).reshape(k, n, -1).numpy()
        out = np.full((k, n, self.task_actions), NOT_RANKED, dtype=np.float32)
        out[:, :, self.amap[ok]] = np.where(emask[:, :, ok], elogp[:, :, ok], NOT_RANKED)
        return out


class FollowExpert:
    """A policy: the whole team takes the expert's best-ranked valid action at every step,
    the action Alg. 5.1 offers each agent first, through the expert's adapter. What a shared
    model would teach on a task it was not trained for, measured before (or after) using it:
    how a requester reviews an expert (``drlaas eval --as-expert``). The expert is loaded
    afresh for every batch of episodes, so a stateful one (a baseline) starts clean."""

    def __init__(self, ref: str, seed: int = 0, name: str | None = None):
        self.ref, self.seed, self.name = ref, seed, name or ref

    def reset(self, env: Any) -> None:
        self.expert = load_expert(self.ref, env.spec, self.seed)

    def act(self, env: Any) -> np.ndarray:
        scores = self.expert.scores(env)
        return np.where(np.asarray(env.action_mask()), scores, -np.inf).argmax(-1)


# ---------------------------------------------------------------------------- loading


def load_expert(ref: str, task: Any, seed: int = 0) -> Any:
    """The expert named by ``ref`` for a task with EnvSpec ``task``.

    ``ref`` is a built-in (``oracle``, ``bayes``, ``uniform``, ``random``, ``biased:K``,
    ``malicious:REF``) or a model directory (``model.json`` + ``model.safetensors``); write
    ``./oracle`` for a directory that has a built-in's name. Built-in names come first.
    Loading by CID is the platform's job (``workers/daemon/experts.py``): it fetches and
    verifies the model, then passes its directory. ``seed`` seeds the random expert.
    """
    if not isinstance(ref, str) or not ref:
        raise ExpertError(f"expert reference must be a non-empty string, got {ref!r}")
    if ref == "oracle":
        return OracleExpert()
    if ref == "random":
        return RandomExpert(seed)
    if ref in BASELINES:  # bayes, uniform
        return PolicyExpert(make_baseline(ref, seed), ref)
    kind, _, arg = ref.partition(":")
    if kind == "biased" and arg:
        try:
            action = int(arg)
        except ValueError:
            raise ExpertError(f"expert {ref!r}: biased:K needs an action index K") from None
        return BiasedExpert(action, task.num_actions, ref)
    if kind == "malicious" and arg:
        return MaliciousExpert(load_expert(arg, task, seed), ref)
    path = Path(ref)
    if not (path / "model.json").is_file():
        raise ExpertError(f"expert {ref!r}: not a model directory (no model.json) and not a "
                          f"built-in ({', '.join(BUILTINS)})")
    from workers.mdrl.modelio import load_model

    try:
        policy = load_model(path)
    except (OSError, ValueError, KeyError, RuntimeError) as exc:
        raise ExpertError(f"expert {ref!r}: cannot load the model ({exc})") from exc
    return ModelExpert(policy, task, ref)


def load_experts(refs: list[str] | tuple[str, ...], task: Any, seed: int = 0,
                 dirs: Mapping[str, str | Path] | None = None) -> list[Any]:
    """``load_expert`` for each reference; the i-th random expert is seeded ``seed + i`` so
    five random experts are five different ones. ``dirs`` maps references (model CIDs) to the
    directories they were fetched into: those load from there, named by the reference."""
    dirs = dirs or {}
    return [load_expert_at(r, dirs[r], task, seed + i) if r in dirs
            else load_expert(r, task, seed + i) for i, r in enumerate(refs)]


def load_expert_at(ref: str, directory: str | Path, task: Any, seed: int = 0) -> Any:
    """The model in ``directory`` as an expert named ``ref`` (e.g. the CID it was fetched by:
    what the trained model's card lists, not a local path)."""
    expert = load_expert(str(directory), task, seed)
    expert.name = ref
    return expert
