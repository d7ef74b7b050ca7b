"""Observation builders for CMTL, DMTL and ODMTL (thesis sections 3.4.1, 3.5.1, 3.6.1, 4.3).

An observer turns the state of ``B`` environments stepped together into the stacked 2D maps
the actor and critic CNNs read (Table 3.1). Every builder only READS these attributes of the
env: ``pos`` int (B, N), ``readings`` float (B, C), ``visits`` float (B, C), ``walls`` bool
(B, C) (only when wall maps are on), ``past_pos(k) -> (B, N)`` (ODMTL only) — see
``docs/mdrl-core.md``. ``C = rows * cols`` and ``cell = row * cols + col``.

Channel order (``Observer.actor_channels`` / ``critic_channels`` name them):

* CMTL (3.4.1) actor = critic: N location maps (agent order), readings, visits [, walls].
* DMTL (3.5.1) actor per agent: own location, other agents' counts (dropped when N == 1,
  Table 3.4 footnote), readings, visits [, walls]; critic: all-agent counts, readings,
  visits [, walls].
* ODMTL (3.6.1) actor per agent, each ``w x w``: windowed own location, windowed readings,
  downsized own location, downsized other locations (dropped when N == 1), downsized
  readings, downsized visits [, windowed walls, downsized walls]; critic: downsized
  all-agent counts, readings, visits [, downsized walls].

Wall maps are included iff ``ObservationSpec.walls`` is True, or it is None and the env can
have walls (``spec.walls[1] > 0``). Belief maps (``ObservationSpec.belief``) come last: DMTL and
CMTL add the full posterior map to actor and critic; ODMTL adds a windowed and a downsized
belief to the actor and a downsized (or, with the full critic, full) belief to the critic.

Options beyond the thesis (issue 9: what the thesis-faithful input throws away):

* ``readings="mean"``: each cell shows the mean of all readings taken there, not the last one
  (with the visit counts beside it, the sufficient statistic of the Poisson readings).
* ``scale="fixed"``: readings are ``log(1 + r) / log(1 + r_ref)``, with ``r_ref`` the expected
  count one cell away from a source of the spec's strongest intensity, instead of dividing by
  the episode's (noisy) maximum, which throws away the absolute level that carries distance.
* ``belief=True``: the team posterior over the target cell (``belief.BeliefFilter``, the
  Bayesian searcher's filter), divided by its maximum.
* ``route=True`` (ODMTL with the belief): where to walk. With walls from the sides the
  straight line to the posterior's mass is often blocked, and the way around a wall's free end
  lies outside a 7 x 7 window and is blurred away in the downsized walls map; agents that
  knew the source's cell oscillated against the wall (the failures of the 30 x 30 belief
  policy). The map gives each window cell's expected walking distance (BFS over the walls)
  to the posterior's most probable cells, relative to the agent's own cell. It uses only
  what the agents observe (walls, readings, positions), as the belief does.

Chapter 4 embeds walls with a CAE (``ObservationSpec.walls_embedding``, ``cae.py``): the frozen
encoder turns the full walls map into a d-vector that replaces the downsized walls maps (ODMTL
keeps the windowed one: the 9 reduced inputs of Fig. 4.2; DMTL/CMTL keep their full map) and is
given to the actor and the critic (4.5). So that the rollout, PPO and model files keep carrying
ONE (C, H, W) stack per sample, the d-vector rides in ``k = ceil(d / (H * W))`` extra planes at
the end of each stack (``walls_code_*``: the vector, flattened row-major, zero padded); the
networks cut those planes off before the convolutions and concatenate the vector to the
flattened conv features (Fig. 4.4). Without the option the (windowed / downsized) walls maps
stand in for it, so the actor sees walls without a pretrained encoder.

Choices the thesis leaves open (ours):

* Normalisation (line 712): each FULL ``m x n`` map is divided by its own maximum when that is
  > 0 (per env, and per agent for per-agent maps), BEFORE windowing or downsizing. So a
  window or a downsized map is a view of the normalised full map; its own maximum may be < 1.
* Windows (3.6.1): ``w x w`` centred on the agent's position at step ``t - (w-1)/2``
  (``env.past_pos((w-1)//2)``); cells outside the grid read 0 (also in the walls window).
  An agent moves at most one cell per step in each axis, so its current cell is always
  inside its window.
* Downsizing (3.6.1): Gaussian filter sigma = 1 with ``scipy.ndimage`` semantics,
  ``mode="nearest"`` (edge cells are not darkened, so an agent in a corner keeps its weight)
  and ``truncate=4``; then bilinear resize to ``w x w`` with ALIGN-CORNERS semantics (output
  corners sample the input corner cells, as ``scipy.ndimage.zoom(order=1,
  grid_mode=False)``). The chain is linear and separable, so it is one precomputed matrix
  ``R`` (w*w, C) = kron(Zr Gr, Zc Gc) and a batch of maps is downsized by ``maps @ R.T``.

How it is computed: a step changes the maps only at the agents' cells, so an observer keeps
each env's maps (``_Kept``: transformed readings, visits, their maxima; for ODMTL the visits
and walls downsized in exact fixed point) and updates them there (``Observer._sync``, for envs
with ``episode_id`` and ``t``; others get fresh maps every call). ODMTL stacks are then written
by one compiled pass (``kernels.odmtl_fill``). The result depends only on the env's state.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from scipy import ndimage

from workers.mdrl import kernels
from workers.mdrl.belief import BeliefFilter

KINDS = ("odmtl", "dmtl", "cmtl")
GAUSSIAN_SIGMA = 1.0
ROUTE_CELLS = 4
"""How many of the posterior's most probable cells the walking-distance map (``route``)
averages over: one BFS each per env and step (~20-30 us each at 30 x 30 here)."""


MAX_WALLS_EMBEDDING = 1024
"""Largest walls embedding d an observation takes (the thesis: 128; a CAE bundle holds at most
cae.MAX_CAE_EMBEDDING = 1024): the actor and critic
inputs grow with d times the grid, and an unbounded d in a config grew memory to 7-14 GB
before any error (audit of 2026-12-03)."""

@dataclass(frozen=True)
class ObservationSpec:
    """Which observation model to build (Table 3.1 columns) and its hyperparameters."""

    kind: str = "odmtl"
    """'odmtl' | 'dmtl' | 'cmtl' (sections 3.6, 3.5, 3.4)."""
    window: int = 3
    """w: side of the windowed and downsized ODMTL maps; odd, 1 < w < min(rows, cols)."""
    walls: bool | None = None
    """Append wall maps; None = iff the env can have walls (``spec.walls[1] > 0``)."""
    critic: str = "reduced"
    """ODMTL critic input: 'reduced' (3.6.2: downsized w x w maps) or 'full' (the m x n joint
    maps, as DMTL's critic). The critic only trains the actor (CLDE), so the deployed actor
    and its Table 3.4 parameter count are the same either way."""

    readings: str = "last"
    """Readings map: 'last' reading per cell (thesis) or 'mean' of every reading there."""
    scale: str = "max"
    """Readings scale: 'max' (divide by the map's maximum, thesis line 712) or 'fixed'
    (log-compressed counts relative to a physical reference count; see the module doc)."""
    belief: bool = False
    """Add the team's posterior map of the target cell (``belief.BeliefFilter``)."""
    others: bool | None = None
    """DMTL/ODMTL map of the other agents; None = iff the team has more than one agent (Table
    3.4). True keeps it (all zeros) for one agent, so one actor can serve any team size."""
    walls_embedding: str | None = None
    """Directory of a walls CAE (``cae.py``, Ch. 4.3): its encoder's embedding of the full walls
    map goes to the actor and critic instead of the downsized walls maps. None: no embedding."""
    walls_embedding_size: int = 128
    """d of that CAE (Table 4.1); sizes the networks before the CAE is loaded."""
    route: bool = False
    """ODMTL with ``belief``: add the walking-distance map (``win_route`` to the actor,
    ``ds_route`` to the critic): the posterior's expected number of moves, around the walls,
    from each cell to the source (module doc). Not in the thesis."""

    def __post_init__(self) -> None:
        if self.readings not in ("last", "mean"):
            raise ValueError(
                f"ObservationSpec.readings must be 'last' or 'mean', got {self.readings!r}"
            )
        if self.scale not in ("max", "fixed"):
            raise ValueError(f"ObservationSpec.scale must be 'max' or 'fixed', got {self.scale!r}")
        if not isinstance(self.belief, bool):
            raise ValueError(f"ObservationSpec.belief must be true or false, got {self.belief!r}")
        if self.kind not in KINDS:
            raise ValueError(f"ObservationSpec.kind must be one of {KINDS}, got {self.kind!r}")
        if isinstance(self.window, bool) or not isinstance(self.window, (int, np.integer)):
            raise ValueError(f"ObservationSpec.window must be an int, got {self.window!r}")
        if self.window < 1 or self.window % 2 == 0:
            raise ValueError(
                f"ObservationSpec.window must be a positive odd int, got {self.window}"
            )
        if self.critic not in ("reduced", "full"):
            raise ValueError(
                f"ObservationSpec.critic must be 'reduced' or 'full', got {self.critic!r}"
            )
        if self.others is not None and not isinstance(self.others, bool):
            raise ValueError(
                f"ObservationSpec.others must be True, False or None, got {self.others!r}"
            )
        if self.walls is not None and not isinstance(self.walls, bool):
            raise ValueError(
                f"ObservationSpec.walls must be True, False or None, got {self.walls!r}"
            )
        if self.walls_embedding is not None and (
            not isinstance(self.walls_embedding, str) or not self.walls_embedding
        ):
            raise ValueError(
                "ObservationSpec.walls_embedding must be a CAE directory or None, "
                f"got {self.walls_embedding!r}"
            )
        if not isinstance(self.route, bool):
            raise ValueError(f"ObservationSpec.route must be true or false, got {self.route!r}")
        if self.route and not (self.belief and self.kind == "odmtl"):
            raise ValueError("ObservationSpec.route needs kind='odmtl' and belief=true (it is "
                             "the belief's walking distance, in the ODMTL windows)")
        size = self.walls_embedding_size
        if (isinstance(size, bool) or not isinstance(size, (int, np.integer))
                or not 1 <= size <= MAX_WALLS_EMBEDDING):
            raise ValueError(
                f"ObservationSpec.walls_embedding_size must be an int in 1..{MAX_WALLS_EMBEDDING}"
                f", got {size!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        """Fields as a dict; the walls-embedding fields only when the option is on, so specs,
        cards and checkpoints without it read exactly as before it existed."""
        d = asdict(self)
        if self.walls_embedding is None:
            del d["walls_embedding"], d["walls_embedding_size"]
        if not self.route:
            del d["route"]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ObservationSpec:
        unknown = set(d) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"unknown ObservationSpec fields: {sorted(unknown)}")
        if "walls_embedding_size" in d and d.get("walls_embedding") is None:
            raise ValueError("ObservationSpec.walls_embedding_size is the walls CAE's d: it "
                             "needs walls_embedding (the CAE's directory or CID)")
        return cls(**d)


@dataclass(frozen=True)
class ChannelLayout:
    """The named input maps of the actor and critic and their (C, H, W) shapes (Table 3.1)."""

    actor: tuple[str, ...]
    critic: tuple[str, ...]
    actor_shape: tuple[int, int, int]
    critic_shape: tuple[int, int, int]
    walls: bool
    full_critic: bool
    embedding: int = 0
    """d of the walls embedding carried in the last planes of both stacks (0: none)."""


def channel_layout(env_spec: Any, obs_spec: ObservationSpec) -> ChannelLayout:
    """Channels and shapes of an observation model, without building anything (the resource
    model sizes networks and buffers from this)."""
    rows, cols, agents = int(env_spec.rows), int(env_spec.cols), int(env_spec.agents)
    kind, w = obs_spec.kind, int(obs_spec.window)
    walls_on = bool(env_spec.walls[1] > 0) if obs_spec.walls is None else obs_spec.walls
    keep_others = agents > 1 if obs_spec.others is None else obs_spec.others
    others = ["others"] if keep_others else []
    walls = ["walls"] if walls_on else []
    if kind == "cmtl":
        actor = [f"location_{i}" for i in range(agents)] + ["readings", "visits"] + walls
        critic = list(actor)
    elif kind == "dmtl":
        actor = ["location"] + others + ["readings", "visits"] + walls
        critic = ["all_locations", "readings", "visits"] + walls
    else:
        actor = (
            ["win_location", "win_readings", "ds_location"]
            + [f"ds_{o}" for o in others]
            + ["ds_readings", "ds_visits"]
            + (["win_walls", "ds_walls"] if walls_on else [])
        )
        critic = ["ds_all_locations", "ds_readings", "ds_visits"] + [f"ds_{x}" for x in walls]
    full_critic = kind == "odmtl" and obs_spec.critic == "full"
    if full_critic:
        critic = ["all_locations", "readings", "visits"] + walls
    embedding = int(obs_spec.walls_embedding_size) if obs_spec.walls_embedding else 0
    if embedding:  # the embedding replaces the downsized walls maps (Fig. 4.2)
        actor = [c for c in actor if c != "ds_walls"]
        critic = [c for c in critic if c != "ds_walls"]
    if obs_spec.belief:
        actor += ["win_belief", "ds_belief"] if kind == "odmtl" else ["belief"]
        critic += ["ds_belief"] if kind == "odmtl" and not full_critic else ["belief"]
    if obs_spec.route:
        actor += ["win_route"]
        critic += ["route" if full_critic else "ds_route"]
    h, wd = (w, w) if kind == "odmtl" else (rows, cols)
    reduced_critic = kind == "odmtl" and not full_critic
    ch, cw = (h, wd) if reduced_critic else (rows, cols)
    if embedding:
        actor += [f"walls_code_{i}" for i in range(-(-embedding // (h * wd)))]
        critic += [f"walls_code_{i}" for i in range(-(-embedding // (ch * cw)))]
    return ChannelLayout(
        tuple(actor),
        tuple(critic),
        (len(actor), h, wd),
        (len(critic), ch, cw),
        walls_on,
        full_critic,
        embedding,
    )


# --------------------------------------------------------------------------- linear operators


def _bilinear_matrix(size_in: int, size_out: int) -> np.ndarray:
    """(size_out, size_in) 1D linear interpolation weights, align-corners semantics."""
    z = np.zeros((size_out, size_in))
    if size_in == 1:
        z[:, 0] = 1.0
        return z
    src = np.arange(size_out) * ((size_in - 1) / (size_out - 1)) if size_out > 1 else np.zeros(1)
    i0 = np.minimum(np.floor(src).astype(int), size_in - 2)
    frac = src - i0
    rows = np.arange(size_out)
    np.add.at(z, (rows, i0), 1.0 - frac)
    np.add.at(z, (rows, i0 + 1), frac)
    return z


def downsize_matrix(rows: int, cols: int, window: int) -> np.ndarray:
    """R (w*w, rows*cols): Gaussian blur (sigma 1, mode nearest) then bilinear resize to w x w.

    Both steps are separable, so R = kron(Zr @ Gr, Zc @ Gc); the 1D Gaussian matrices are the
    unit basis pushed through ``scipy.ndimage.gaussian_filter1d``. ``maps (.., C) @ R.T``
    downsizes flattened maps.
    """
    return np.kron(*downsize_factors(rows, cols, window))


def downsize_factors(rows: int, cols: int, window: int) -> tuple[np.ndarray, np.ndarray]:
    """(Zr Gr (w, rows), Zc Gc (w, cols)): the 1D factors of ``downsize_matrix``.

    Downsizing a batch as two thin products (cols, then rows) costs about
    ``w / rows + w / cols`` of one product with R, what makes ODMTL affordable at 30 x 30.
    """
    g_r = ndimage.gaussian_filter1d(np.eye(rows), GAUSSIAN_SIGMA, axis=0, mode="nearest")
    g_c = ndimage.gaussian_filter1d(np.eye(cols), GAUSSIAN_SIGMA, axis=0, mode="nearest")
    return _bilinear_matrix(rows, window) @ g_r, _bilinear_matrix(cols, window) @ g_c


def window_index(rows: int, cols: int, window: int) -> np.ndarray:
    """(C, w*w) int: cell index of each window element around each centre cell; C (one past the
    last cell) for elements outside the grid, so gathers read a zero pad column there."""
    p = window // 2
    r = np.arange(rows)[:, None, None, None] + np.arange(-p, p + 1)[None, None, :, None]
    c = np.arange(cols)[None, :, None, None] + np.arange(-p, p + 1)[None, None, None, :]
    r, c = np.broadcast_arrays(r, c)  # (rows, cols, w, w)
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    idx = np.where(inside, r * cols + c, rows * cols)
    return idx.reshape(rows * cols, window * window).astype(np.intp)


def _inverse_max(maps: np.ndarray) -> np.ndarray:
    """1 / max over the last axis (cells), or 1 where the maximum is not > 0 (line 712)."""
    return _inverse(maps.max(axis=-1))


def _inverse(top: np.ndarray) -> np.ndarray:
    """1 / top, or 1 where top is not > 0 (``_inverse_max`` of maps whose maxima are ``top``)."""
    return (1.0 / np.where(top > 0, top, 1)).astype(np.float32)


#: Fixed-point scale of the downsizing matrix for integer maps (visits, walls): R * 2**40 is
#: rounded to integers, so the products and every partial sum of ``counts @ R_q.T`` are
#: integers below 2**53, exact in float64 in any order, as long as counts <= EXACT_COUNTS.
FIXED_POINT = 2.0**40
EXACT_COUNTS = 4096


class _Kept:
    """An observer's maps of one env, brought up to date cell by cell (``Observer._sync``).

    Per env row: the transformed readings map and its maximum, a copy of the visits and their
    maximum; for ODMTL (``downsized`` = w * w) also the visits downsized in fixed point (exact,
    so the same whatever the order of the updates), the walls and their downsized map (both
    change only at resets).
    """

    def __init__(self, env: Any, b: int, cells: int, downsized: int) -> None:
        self.env, self.episode, self.t = env, None, None
        self.readings = np.zeros((b, cells), dtype=np.float32)
        self.readings_top = np.zeros(b, dtype=np.float32)
        self.visits = np.zeros((b, cells), dtype=np.float32)
        self.visits_top = np.zeros(b, dtype=np.float32)
        self.ds_visits = np.zeros((b, downsized))  # fixed point (FIXED_POINT)
        # visits are integers <= EXACT_COUNTS, so ds_visits is exact (and kept at all)
        self.exact = downsized > 0
        self.walls = np.zeros((b if downsized else 0, cells), dtype=bool)  # ODMTL's windows
        self.ds_walls = np.zeros((b, downsized), dtype=np.float32)


def _normalise(maps: np.ndarray) -> np.ndarray:
    """Divide each map (last axis = cells) by its maximum when that is > 0 (line 712)."""
    return maps * _inverse_max(maps)[..., None]


# --------------------------------------------------------------------------- joint actions (CMTL)
MAX_JOINT_ACTIONS = 2**20
"""Largest CMTL joint action space A**N an observer is built for (5 actions: 8 agents; 9
actions: 6): the actor's output layer, the policy masks of every rollout step and the logits
of a minibatch all hold A**N values, 5**20 of them is petabytes."""


def check_joint_actions(num_actions: int, agents: int) -> None:
    """ValueError when CMTL's joint action space A**N exceeds MAX_JOINT_ACTIONS (before
    anything of that size is allocated)."""
    joint = num_actions**agents
    if joint > MAX_JOINT_ACTIONS:
        raise ValueError(
            f"CMTL's joint actor picks one of {num_actions}**{agents} = {joint:.3g} joint "
            f"actions ({num_actions} actions per agent, {agents} agents), more than "
            f"{MAX_JOINT_ACTIONS:,}: use dmtl or odmtl (one shared actor per agent) or fewer "
            f"agents")


def encode_joint(actions: np.ndarray, num_actions: int) -> np.ndarray:
    """(B, N) per-agent actions -> (B,) joint index; agent 0 is the most significant digit."""
    actions = np.asarray(actions)
    n = actions.shape[-1]
    if actions.size and (actions.min() < 0 or actions.max() >= num_actions):
        raise ValueError(
            f"actions must lie in [0, {num_actions}), got range [{actions.min()}, {actions.max()}]"
        )
    weights = num_actions ** np.arange(n - 1, -1, -1, dtype=np.int64)
    return (actions.astype(np.int64) * weights).sum(-1)


def decode_joint(joint: np.ndarray, num_actions: int, agents: int) -> np.ndarray:
    """(B,) joint index -> (B, N) per-agent actions (inverse of ``encode_joint``)."""
    joint = np.asarray(joint, dtype=np.int64)
    if joint.size and (joint.min() < 0 or joint.max() >= num_actions**agents):
        raise ValueError(
            f"joint actions must lie in [0, {num_actions**agents}), got range "
            f"[{joint.min()}, {joint.max()}]"
        )
    weights = num_actions ** np.arange(agents - 1, -1, -1, dtype=np.int64)
    return (joint[..., None] // weights) % num_actions


def joint_mask(mask: np.ndarray) -> np.ndarray:
    """bool (B, N, A) -> (B, A**N): a joint action is valid iff every agent's action is."""
    mask = np.asarray(mask, dtype=bool)
    out = mask[:, 0]
    for i in range(1, mask.shape[1]):  # N outer products, each O(B * A**(i+1))
        out = (out[:, :, None] & mask[:, i, None, :]).reshape(mask.shape[0], -1)
    return out


# --------------------------------------------------------------------------- observer


class Observer:
    """Builds (actor, critic) observations for a batch of envs; see the module docstring."""

    def __init__(
        self,
        env_spec: Any,
        obs_spec: ObservationSpec,
        walls_encoder: Any = None,
        any_window: bool = False,
    ) -> None:
        rows, cols, agents = int(env_spec.rows), int(env_spec.cols), int(env_spec.agents)
        if rows < 1 or cols < 1 or agents < 1:
            raise ValueError(
                f"env spec needs rows, cols, agents >= 1, got {rows}, {cols}, {agents}"
            )
        w = int(obs_spec.window)
        if obs_spec.kind == "odmtl" and not (1 < w and (any_window or w < min(rows, cols))):
            rule = "w > 1" if any_window else f"1 < w < min(rows, cols) = {min(rows, cols)}"
            raise ValueError(f"ODMTL window must satisfy {rule} (thesis 3.6.1), got w = {w}")
        self.env_spec, self.obs_spec = env_spec, obs_spec
        self.kind, self.window = obs_spec.kind, w
        self.rows, self.cols, self.agents = rows, cols, agents
        self.cells = rows * cols
        layout = channel_layout(env_spec, obs_spec)
        self.walls, self.full_critic = layout.walls, layout.full_critic
        self.has_others = any(c.endswith("others") for c in layout.actor)
        self.joint_actions = self.kind == "cmtl"
        if self.joint_actions and getattr(env_spec, "num_actions", None) is not None:
            check_joint_actions(int(env_spec.num_actions), agents)
        self.actor_channels, self.critic_channels = layout.actor, layout.critic
        self.actor_shape, self.critic_shape = layout.actor_shape, layout.critic_shape
        self.embedding = layout.embedding
        self.embedder = self._walls_embedder(walls_encoder) if self.embedding else None
        if self.kind == "odmtl":
            self._rt = downsize_matrix(rows, cols, w).T.astype(np.float32).copy()  # (C, w*w)
            a_r, a_c = downsize_factors(rows, cols, w)
            # zero columns pad w to a multiple of 8: BLAS kernels run 8 floats at a time, and
            # the padded products are ~2x faster than the exact-width ones at 30 x 30
            pad = -(-w // 8) * 8
            self._ar_t = np.zeros((rows, pad), dtype=np.float32)  # (rows, w) + zero columns
            self._ar_t[:, :w] = a_r.T
            self._ac_t = np.zeros((cols, pad), dtype=np.float32)
            self._ac_t[:, :w] = a_c.T
            win = window_index(rows, cols, w)
            # off-grid window elements read cell 0 and are then multiplied by 0
            self._win = np.where(win < self.cells, win, 0)
            self._win_inside = (win < self.cells).astype(np.float32)
            self._pad = w // 2  # window centre lags by (w-1)/2 steps (3.6.1)
            # integer (fixed-point) R^T for integer maps: exact products and sums in float64
            rq_t = np.round(downsize_matrix(rows, cols, w).T * FIXED_POINT)  # (C, w*w)
            self._rq_t = np.ascontiguousarray(rq_t)  # rows of cells: the kernels read them
        else:
            self._rq_t = np.zeros((self.cells, 0))  # DMTL / CMTL keep no downsized maps
        self._not_self = (~np.eye(agents, dtype=bool)).astype(np.int64)
        self._pair_i, self._pair_j = np.divmod(np.arange(agents * agents), agents)
        self._buffers: dict[tuple, np.ndarray] = {}  # scratch space per batch size
        # the maps of the last two envs observed, kept up to date cell by cell (``_sync``)
        self._kept: dict[int, _Kept] = {}
        self._belief = BeliefFilter(env_spec) if obs_spec.belief else None
        if obs_spec.scale == "fixed":
            ref = reference_count(env_spec)
            self._log_ref = np.float32(np.log1p(ref))
            if not self._log_ref >= MIN_LOG_REFERENCE:  # the unit of every reading map
                raise ValueError(
                    f"the fixed readings scale's unit (the expected count one cell from the "
                    f"strongest source, Eq. 6) is {ref:.3g} here: readings would divide by "
                    f"~0 (NaN / inf inputs). Raise env.intensity, env.dwell_min or "
                    f"env.detector_area_cm2, or use observation.scale 'max'"
                )

    def num_actor_outputs(self, num_actions_per_agent: int) -> int:
        """A for the shared CLDE actor (DMTL/ODMTL), A**N for the joint CMTL actor."""
        a = int(num_actions_per_agent)
        if self.joint_actions:
            check_joint_actions(a, self.agents)
        return a**self.agents if self.joint_actions else a

    # ------------------------------------------------------------------ helpers
    def _walls_embedder(self, given: Any) -> Any:
        """The CAE encoder (``cae.WallsEmbedder``): ``given`` (e.g. rebuilt from a model file)
        or loaded from ``obs_spec.walls_embedding``; checked against this grid and d."""
        from workers.mdrl.cae import WallsEmbedder

        embedder = given if given is not None else WallsEmbedder.load(self.obs_spec.walls_embedding)
        if tuple(embedder.grid) != (self.rows, self.cols):
            raise ValueError(
                f"walls CAE {embedder.source!r} encodes {embedder.grid[0]}x"
                f"{embedder.grid[1]} maps; this env is {self.rows}x{self.cols}"
            )
        if embedder.size != self.embedding:
            raise ValueError(
                f"walls CAE {embedder.source!r} has d = {embedder.size}; the "
                f"observation spec says walls_embedding_size = {self.embedding}"
            )
        return embedder

    def _write_embedding(self, env: Any, actor: np.ndarray, critic: np.ndarray) -> None:
        """The walls embedding (B, d), flattened into the last planes of both stacks."""
        code = self.embedder.embed(env.walls)
        d = self.embedding
        for arr in (actor, critic):  # (B, [N,] C, cells): the code planes are the last k
            k = -(-d // arr.shape[-1])
            planes = arr[..., -k:, :].reshape(*arr.shape[:-2], -1)
            planes[..., d:] = 0.0
            planes[..., :d] = code.reshape(code.shape[0], *([1] * (arr.ndim - 3)), d)
            arr[..., -k:, :] = planes.reshape(*arr.shape[:-2], k, arr.shape[-1])

    def _check(self, env: Any) -> tuple[np.ndarray, int]:
        pos = np.asarray(env.pos)
        if pos.ndim != 2 or pos.shape[1] != self.agents:
            raise ValueError(f"env.pos must have shape (B, {self.agents}), got {pos.shape}")
        if np.shape(env.readings) != (pos.shape[0], self.cells):
            raise ValueError(
                f"env.readings must have shape ({pos.shape[0]}, {self.cells}), "
                f"got {np.shape(env.readings)}"
            )
        return pos, pos.shape[0]

    def _buffer(self, key: tuple, shape: tuple[int, ...]) -> np.ndarray:
        """Scratch array reused across calls (per batch size), never returned to the caller."""
        buf = self._buffers.get(key)
        if buf is None or buf.shape != shape:
            buf = self._buffers[key] = np.empty(shape, dtype=np.float32)
        return buf

    def _window_index(self, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """centre (B, N) cells -> flat indices into a (B, C) map and the inside mask, both
        (B, N, w*w): one computation serves every windowed map of a call."""
        flat = self._win[centre]
        flat += (np.arange(centre.shape[0]) * self.cells)[:, None, None]
        return flat, self._win_inside[centre]

    @staticmethod
    def _gather_windows(maps: np.ndarray, index: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """maps (B, C) -> (B, N, w*w) windows at ``_window_index``'s cells (0 off-grid)."""
        flat, inside = index
        out = np.take(maps.reshape(-1), flat)
        out *= inside
        return out

    def _downsize(self, maps: list[np.ndarray]) -> np.ndarray:
        """k maps (B, C) float32 -> (k, B, w, w) downsized maps (``maps @ R.T`` in two thin
        products, ``downsize_factors``); a strided view of a scratch buffer."""
        k, b = len(maps), maps[0].shape[0]
        rows, cols, w, pad = self.rows, self.cols, self.window, self._ac_t.shape[1]
        if self.cells * w * w <= (self.cells + w * rows) * pad:  # small grid: one product
            out = self._buffer(("ds_full", b, k), (k, b, w * w))
            for j, m in enumerate(maps):
                np.matmul(m, self._rt, out=out[j])
            return out.reshape(k, b, w, w)
        by_col = self._buffer(("ds_cols", b, k), (k, b * rows, pad))  # [j, (b, r), kc]
        for j, m in enumerate(maps):
            np.matmul(m.reshape(b * rows, cols), self._ac_t, out=by_col[j])
        swapped = self._buffer(("ds_swap", b, k), (k, b, w, rows))  # [j, b, kc, r]
        np.copyto(swapped, by_col.reshape(k, b, rows, pad)[..., :w].transpose(0, 1, 3, 2))
        both = self._buffer(("ds_both", b, k), (k, b, w, pad))  # [j, b, kc, ir]
        np.matmul(swapped.reshape(k * b * w, rows), self._ar_t, out=both.reshape(k * b * w, pad))
        return both[..., :w].transpose(0, 1, 3, 2)

    # ------------------------------------------------------------------ observe
    def observe(
        self, env: Any, out: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """-> actor (B, N, C_a, H, W) (CMTL: (B, 1, ...)), critic (B, C_c, H, W), float32.

        ``out``: optional preallocated (actor, critic) float32 arrays of those shapes (e.g.
        slices of a rollout buffer) to write into instead of allocating new ones.
        """
        pos, b = self._check(env)
        if out is not None:
            self._check_out(out, b)
        kept = self._sync(env, b)
        if self.kind == "odmtl":
            actor, critic = self._observe_odmtl(env, kept, pos, b, out)
        else:
            readings, visits = kept.readings, kept.visits
            # the walls map is binary, so it is already normalised
            walls = np.asarray(env.walls, dtype=np.float32) if self.walls else None
            shown = readings if self.obs_spec.scale == "fixed" else _normalise(readings)
            actor, critic = self._observe_full(pos, b, shown, _normalise(visits), walls, out)
        if self._belief is not None:
            self._write_belief(env, actor, critic)
        if self.embedder is not None:
            self._write_embedding(env, actor, critic)
        return (actor.reshape((b, -1) + self.actor_shape), critic.reshape((b,) + self.critic_shape))

    def _readings_cells(self, env: Any, rows: Any, cells: Any) -> np.ndarray:
        """The transformed readings of ``[rows, cells]`` (index arrays or slices), float32;
        ``cells`` None: ``rows`` are flat indices into the (B, C) maps."""

        def at(maps: Any) -> np.ndarray:
            maps = np.asarray(maps)
            return maps.reshape(-1)[rows] if cells is None else maps[rows, cells]

        if self.obs_spec.readings == "mean":
            total = at(env.reading_sum).astype(np.float64, copy=False)
            # a cell never visited has sum 0, so max(visits, 1) gives it mean 0 without a mask
            maps = total / np.maximum(at(env.visits), 1)
        else:
            maps = np.array(at(env.readings), dtype=np.float64)
        if self.obs_spec.scale == "fixed":
            np.log1p(maps, out=maps)
            maps /= self._log_ref
        return maps.astype(np.float32)

    def _write_belief(self, env: Any, actor: np.ndarray, critic: np.ndarray) -> None:
        """Posterior map / its maximum into its actor and critic channels (cells flat), and
        the walking-distance maps (``route``) computed from the same posterior."""
        exact = self._belief.posterior(env)
        post = exact.astype(np.float32)
        post *= _inverse_max(post)[:, None]
        a_names, c_names = self.actor_channels, self.critic_channels
        if self.kind == "odmtl":
            centre = np.asarray(env.past_pos(self._pad))
            index = self._window_index(centre)
            actor[:, :, a_names.index("win_belief")] = self._gather_windows(post, index)
            ds = post @ self._rt
            actor[:, :, a_names.index("ds_belief")] = ds[:, None]
            critic[:, c_names.index("belief" if self.full_critic else "ds_belief")] = (
                post if self.full_critic else ds)
            if self.obs_spec.route:
                self._write_route(env, exact, index, actor, critic)
        else:
            actor[:, :, a_names.index("belief")] = post[:, None]
            critic[:, c_names.index("belief")] = post

    def _write_route(self, env: Any, post: np.ndarray, index: tuple[np.ndarray, np.ndarray],
                     actor: np.ndarray, critic: np.ndarray) -> None:
        """The walking-distance maps (module doc, ``route``). ``g[b, x]`` = the expected BFS
        steps from cell x to the source over the ``ROUTE_CELLS`` most probable cells of the
        posterior (their probabilities renormalised). The actor's window shows, per cell,
        how many steps nearer (+) or farther (-) it is than the agent's own cell, over w // 2
        and clipped to [-1, 1] (walls, other pockets and off-grid cells read -1); the critic
        gets g over the grid's walking scale (rows + cols), clipped to 1, downsized."""
        k = min(ROUTE_CELLS, self.cells)
        # ties (cells the readings cannot tell apart) go to the lower cell index, and float
        # noise below 1e-12 does not reorder them: the same state gives the same map in any batch
        top = np.argsort(-np.round(post, 12), axis=1, kind="stable")[:, :k]  # (B, k)
        weight = np.take_along_axis(post, top, axis=1)
        total = weight.sum(axis=1, keepdims=True)
        weight = np.where(total > 0, weight / np.where(total > 0, total, 1.0), 1.0 / k)
        steps = np.minimum(env.walking_steps(top), self.rows * self.cols)  # (B, k, C)
        g = np.einsum("bk,bkc->bc", weight.astype(np.float32), steps.astype(np.float32))
        here = np.take_along_axis(g, np.asarray(env.pos), axis=1)  # (B, N)
        flat, inside = index
        win = np.take(g.reshape(-1), flat)  # (B, N, w*w)
        rel = (here[:, :, None] - win) / max(self.window // 2, 1)
        np.clip(rel, -1.0, 1.0, out=rel)
        rel = rel * inside - (1.0 - inside)
        actor[:, :, self.actor_channels.index("win_route")] = rel
        scaled = np.minimum(g / float(self.rows + self.cols), 1.0).astype(np.float32)
        if self.full_critic:
            critic[:, self.critic_channels.index("route")] = scaled
        else:
            critic[:, self.critic_channels.index("ds_route")] = scaled @ self._rt

    def _check_out(self, out: tuple[np.ndarray, np.ndarray], b: int) -> None:
        n = 1 if self.joint_actions else self.agents
        want = ((b, n) + self.actor_shape, (b,) + self.critic_shape)
        for name, arr, shape in zip(("actor", "critic"), out, want, strict=True):
            if arr.shape != shape or arr.dtype != np.float32 or not arr.flags.c_contiguous:
                raise ValueError(
                    f"out {name} must be a C-contiguous float32 array of shape "
                    f"{shape}, got {arr.dtype} {arr.shape}"
                )

    @staticmethod
    def _outputs(out, actor_shape, critic_shape):
        """Flat-cell views of the caller's buffers, or new arrays."""
        if out is None:
            return np.empty(actor_shape, np.float32), np.empty(critic_shape, np.float32)
        return out[0].reshape(actor_shape), out[1].reshape(critic_shape)

    def _occupancy(self, pos: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
        """-> (B, N) agents on each agent's cell, (B, N) max of each agent's others map.

        Agent i's others map is nonzero only at the cells of agents j != i, where it holds
        at_cell[j] - [pos_j == pos_i]; so its maximum (the normaliser, line 712) comes from
        an (N, N) comparison instead of a pass over the full map. It is >= 1 when N > 1.
        """
        n = self.agents
        same = (pos[:, self._pair_i] == pos[:, self._pair_j]).reshape(b, n, n)
        at_cell = same.sum(-1)
        top_others = ((at_cell[:, None, :] - same) * self._not_self).max(-1)
        return at_cell, np.maximum(top_others, 1).astype(np.float32)

    def _observe_full(self, pos, b, readings, visits, walls, out):
        n, c = self.agents, self.cells
        tail = [readings, visits] + ([walls] if walls is not None else [])
        if self.kind == "cmtl":
            actor, critic = self._outputs(
                out, (b, 1, self.actor_shape[0], c), (b, self.critic_shape[0], c)
            )
            own = actor[:, 0, :n]  # (B, N, C) one-hot location maps, max 1
            own[...] = 0.0
            np.put_along_axis(own, pos[:, :, None], 1.0, axis=-1)
            for k, m in enumerate(tail):
                actor[:, 0, n + k] = m
            critic[...] = actor[:, 0]
            return actor, critic
        actor, critic = self._outputs(
            out, (b, n, self.actor_shape[0], c), (b, self.critic_shape[0], c)
        )
        own = actor[:, :, 0]
        own[...] = 0.0
        np.put_along_axis(own, pos[:, :, None], 1.0, axis=-1)
        counts = own.sum(axis=1)  # (B, C) agents per cell
        at_cell, top_others = self._occupancy(pos, b)
        k = 1
        if self.has_others:
            np.subtract(counts[:, None, :], own, out=actor[:, :, 1])
            actor[:, :, 1] *= (1.0 / top_others)[:, :, None]
            k = 2
        for m in tail:
            actor[:, :, k] = m[:, None, :]
            k += 1
        critic[:, 0] = counts * (1.0 / at_cell.max(1, keepdims=True)).astype(np.float32)
        for j, m in enumerate(tail):
            critic[:, 1 + j] = m
        return actor, critic

    def _sync(self, env: Any, b: int) -> _Kept:
        """The kept maps of ``env`` (``_Kept``), up to date.

        A row that stepped once since the last call (same ``episode_id``, ``t`` one more)
        changed only at the agents' current cells, the only cells a step reads at, so only
        those are recomputed (and the fixed-point downsized visits get the visits' change
        there); every other row (reset, several steps or none, restored) is recomputed whole.
        Same formulas per cell, so the maps equal a fresh computation bit for bit. Envs without
        ``episode_id``/``t`` (duck-typed ones) get fresh maps every call.

        The cell update runs on all rows (whole arrays index faster than a selection of rows)
        and keeps each row consistent with itself, so the rows recomputed after it lose
        nothing by it."""
        episode, t = getattr(env, "episode_id", None), getattr(env, "t", None)
        kept = self._kept.get(id(env)) if episode is not None and t is not None else None
        if kept is None or kept.env is not env or len(kept.readings) != b:
            kept = _Kept(env, b, self.cells, self._rq_t.shape[1])
            redo = np.arange(b)
        else:
            self._sync_cells(env, kept)
            redo = np.flatnonzero((kept.episode != episode) | (t != kept.t + 1))
        if len(redo):
            self._sync_rows(env, kept, redo)
        if episode is not None and t is not None:
            kept.episode, kept.t = np.array(episode), np.array(t)
            if id(env) not in self._kept and len(self._kept) >= 2:
                self._kept.pop(next(iter(self._kept)))
            self._kept[id(env)] = kept
        return kept

    def _sync_rows(self, env: Any, kept: _Kept, rows: np.ndarray) -> None:
        """Recompute the kept maps of ``rows`` whole (the visits and walls products only for
        rows whose visits or walls differ from the kept copy)."""
        if self.obs_spec.readings != "mean" and self.obs_spec.scale != "fixed":
            readings = np.asarray(env.readings)[rows].astype(np.float32)
        else:
            readings = self._readings_cells(env, rows, slice(None))
        kept.readings[rows] = readings
        if self.obs_spec.scale != "fixed":
            kept.readings_top[rows] = readings.max(1)
        visits = np.asarray(env.visits)[rows].astype(np.float32)
        new = (visits != kept.visits[rows]).any(1)
        if new.any():
            rows, visits = rows[new], visits[new]
            kept.visits[rows] = visits
            kept.visits_top[rows] = visits.max(1)
            kept.exact &= _small_counts(visits)
            if kept.exact:
                kept.ds_visits[rows] = kernels.fixed_point_sum(visits, self._rq_t)
        if self.walls and self.kind == "odmtl":
            walls = np.asarray(env.walls)[rows].astype(bool)
            new = (walls != kept.walls[rows]).any(1)
            if new.any():
                rows, walls = rows[new], walls[new]
                kept.walls[rows] = walls
                kept.ds_walls[rows] = _fixed_point(walls, self._rq_t)

    def _sync_cells(self, env: Any, kept: _Kept) -> None:
        """Update the kept maps at the agents' current cells (right for rows that stepped once
        since; for the others, they stay consistent: maxima and the downsized visits follow
        the kept maps)."""
        cells = np.ascontiguousarray(env.pos, dtype=np.int64)  # (B, N)
        flat = (np.arange(len(cells)) * self.cells)[:, None] + cells  # into (B, C) maps
        if self.obs_spec.readings != "mean" and self.obs_spec.scale != "fixed":
            new_r = np.asarray(env.readings).reshape(-1)[flat].astype(np.float32)
        else:
            new_r = self._readings_cells(env, flat, None)
        new_v = np.asarray(env.visits).reshape(-1)[flat].astype(np.float32)
        kept.exact = kernels.kept_cells(
            cells, new_r, new_v, kept.readings, kept.readings_top,
            self.obs_spec.scale != "fixed",  # the maximum only matters on the 'max' scale
            kept.visits, kept.visits_top, kept.ds_visits, self._rq_t, kept.exact,
        )

    def _observe_odmtl(self, env, kept, pos, b, out):
        """The ODMTL stacks from the kept maps (``_sync``) by one compiled pass
        (``kernels.odmtl_fill``). The downsized readings are a float32 product, the downsized
        visits and walls exact fixed point (within 3e-7 of float32 products); the stacks are a
        function of the env's state alone, whatever steps led to it."""
        w, ww, p = self.window, self.window**2, self._pad
        centre = np.asarray(env.past_pos(p))
        if centre.shape != pos.shape:
            raise ValueError(f"env.past_pos({p}) must have shape {pos.shape}, got {centre.shape}")
        pos = np.ascontiguousarray(pos, dtype=np.int64)
        centre = np.ascontiguousarray(centre, dtype=np.int64)
        critic_cells = self.cells if self.full_critic else ww
        actor, critic = self._outputs(
            out, (b, self.agents, self.actor_shape[0], ww), (b, self.critic_shape[0], critic_cells)
        )
        fixed = self.obs_spec.scale == "fixed"
        inv_r = np.ones(b, np.float32) if fixed else _inverse(kept.readings_top)
        inv_v = _inverse(kept.visits_top)
        if kept.exact:
            ds_r = self._downsize([kept.readings])[0]
            ds_v = (kept.ds_visits / FIXED_POINT).astype(np.float32)
        else:  # visits that are not small integers: a float32 product as for the readings
            ds_r, ds_v = self._downsize([kept.readings, kept.visits])
        ds_r = np.ascontiguousarray(ds_r).reshape(b, ww)
        ds_v = np.ascontiguousarray(ds_v).reshape(b, ww)
        walls_at = (4 if self.has_others else 3) + 2 if self.walls else 0
        ds_w = kept.ds_walls if self.walls and not self.embedding else np.zeros((0, ww), np.float32)
        kernels.odmtl_fill(
            actor, critic, pos, centre, self.rows, self.cols, w, kept.readings, inv_r, ds_r,
            ds_v, inv_v, self._rt, kept.walls, ds_w, self.has_others, walls_at,
            not self.full_critic,
        )
        if self.full_critic:  # the m x n joint maps (DMTL's critic input)
            counts = critic[:, 0]
            counts[...] = 0.0
            for i in range(self.agents):  # one agent at a time: indices unique, += counts all
                counts[np.arange(b), pos[:, i]] += 1.0
            counts /= np.max(counts, axis=1, keepdims=True)
            critic[:, 1] = kept.readings * inv_r[:, None]
            critic[:, 2] = kept.visits * inv_v[:, None]
            if self.walls:
                critic[:, 3] = np.asarray(env.walls, dtype=np.float32)
        return actor, critic


def _fixed_point(counts: np.ndarray, rq_t: np.ndarray) -> np.ndarray:
    """(B, C) small integer counts -> float32 (B, w*w) downsized: exact in fixed point, then
    rounded once."""
    return (kernels.fixed_point_sum(counts, rq_t) / FIXED_POINT).astype(np.float32)


def _small_counts(counts: np.ndarray) -> bool:
    """Counts the fixed-point products take exactly: integers in [0, EXACT_COUNTS]."""
    return bool(
        np.all(counts == np.round(counts))
        and counts.min(initial=0) >= 0
        and counts.max(initial=0) <= EXACT_COUNTS
    )


def _raise_max(top: np.ndarray, maps: np.ndarray, old: np.ndarray, new: np.ndarray) -> None:
    """Keep ``top`` = row maxima of ``maps`` (B, C) after they changed from ``old`` to ``new``
    (B, N) at a few cells: raised where a value grew, recomputed for the rows where a value
    that was the maximum fell."""
    fell = np.flatnonzero(((new < old) & (old >= top[:, None])).any(1))
    np.maximum(top, new.max(1), out=top)
    if len(fell):
        top[fell] = maps[fell].max(1)


MIN_LOG_REFERENCE = 1e-30
"""Least log1p(reference count) the fixed scale divides by: far below any physical setting
(the thesis' is ~1e-1), far above float32's subnormal floor where the division made NaN and inf
observations (intensity 1e-40; audit of 2026-12-03)."""


def reference_count(env_spec: Any) -> float:
    """Expected count one cell side away from a source of the spec's strongest intensity
    (Eq. 6, no walls): the physical unit of the 'fixed' readings scale."""
    cell_cm = (
        min(
            float(a) / n
            for a, n in zip(env_spec.area_m, (env_spec.rows, env_spec.cols), strict=True)
        )
        * 100.0
    )
    strongest = max(env_spec.intensity.values)
    return strongest * env_spec.dwell_min * env_spec.detector_area_cm2 / (4 * np.pi * cell_cm**2)


def make_observer(
    env_spec: Any, obs_spec: ObservationSpec, walls_encoder: Any = None, any_window: bool = False
) -> Observer:
    """Observer for an env spec (needs ``rows``, ``cols``, ``agents``, ``walls`` (min, max)).
    ``walls_encoder``: a ``cae.WallsEmbedder`` to use instead of loading
    ``obs_spec.walls_embedding`` (a model file carries its own encoder). ``any_window``: an
    ODMTL window may be as large as the grid or larger (windows pad off-grid cells, the
    downsizing interpolates up): how a model trained on a larger map reads a smaller one (an
    expert guiding a small task, a model evaluated on another grid); a learner keeps the
    thesis rule w < min(rows, cols) (3.6.1)."""
    if not isinstance(obs_spec, ObservationSpec):
        raise ValueError(f"obs_spec must be an ObservationSpec, got {type(obs_spec).__name__}")
    return Observer(env_spec, obs_spec, walls_encoder, any_window)
