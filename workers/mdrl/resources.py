"""What a training spec costs: estimated peak memory (bytes) and compute (FLOPs, hours).

The gateway refuses specs beyond its platform limits and a worker declines specs beyond its own
RAM, both before anything is allocated: every figure here is integer arithmetic on the spec
(Python ints, so the CMTL joint action space A**N of 16 agents, 5**16, is just a number).

Memory counts what a run holds at its peak: the batched env's arrays (Ch. 3.2 state, the
C x C geometry tables), the observation batch, the rollout buffer [T, B, ...] (actor and
critic maps, masks over the policy's actions, actions, log-probs, values, rewards), the actor
and critic parameters with their gradients and Adam moments, the activations of one minibatch
and a fixed process overhead (Python, numpy, torch). Compute counts the LeNet forward passes of
the rollout, forward + backward (~3x forward) per epoch of the update, and the env/observer
work per step, and with ``selection.keep_best`` the job's greedy evaluations (actor forward
passes and env work of at most JOB_EVAL_EPISODES x max_steps steps every ``eval_every``
updates), spread over the env steps between them; the job's final evaluation (the same size)
is charged once.

The networks a run loads besides its own are counted when their cards are at hand (a worker
reads them before it accepts; ``experts`` and ``walls_cae`` of :func:`estimate`): each MEDC
expert's weights, its observer on the task's grid (the adapter of ``experts.py``: a belief-map
expert on a walled task holds a gain table per env) and one forward pass over every env's
agents; the walls CAE's weights and one encoding of every env's map.

Wall time is compute over a reference rate, plus a fixed cost per PPO update
(:func:`update_overhead_seconds`: Python and torch dispatch per rollout time step and per
optimizer step, and the update's own bookkeeping: GAE, the weights check, the metrics row and
progress point), calibrated so the ODMTL 3-agent 10x10 preset runs at the ~7,000 env steps/s
measured on one thread of a 2-core CPU (presets.FAST_PPO). FLOPs alone made an update of one
env step (``num_envs`` 1, ``horizon`` 1) ~0.01 ms where it takes ~7 ms: a spec of tiny updates
was ~500x cheaper in the deadline check and in worker-hours than it runs. These are estimates
to refuse the absurd, not capacity planning.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

from workers.mdrl.env import HISTORY
from workers.mdrl.evaluate import STEP_ENVS, default_batch
from workers.mdrl.experts import laid_on_task
from workers.mdrl.observations import ROUTE_CELLS, channel_layout
from workers.mdrl.trainingspec import JOB_EVAL_EPISODES, TrainingSpec

PROCESS_BASE_BYTES = 400 * 2**20
"""Python + numpy + torch of a training process before any array (measured RSS ~350 MiB)."""
REFERENCE_PRESET = "odmtl-3a-10x10"
REFERENCE_STEPS_PER_S = 7_000
"""Env steps/s of REFERENCE_PRESET's PPO with REFERENCE_OBSERVATION on one thread of this
project's 2-core CPU (measured before the presets took the belief map)."""
REFERENCE_OBSERVATION = {"kind": "odmtl", "window": 3}
JOINT_ACTION_S = 2e-8
"""Seconds per joint action per env step of CMTL's passes over all A**N joint actions of
each env (the joint mask, the masked log-probabilities' where and fill, log_softmax, argmax),
which the FLOPs of its head (a matmul) do not show: ~20 ns each on this project's CPU with
5**7 and 5**8 joint actions, ~10 ns with 5**6 (2026-12-05, one thread, the machine loaded;
``benchmarks/resource_estimate.py`` has a CMTL spec: measured / estimated 0.64 for an
update, 0.43 for the evaluation; 4.7 and 2.9 without this term). Each learning epoch pays
it again forward and backward."""
UPDATE_FIXED_S = 0.002
ROLLOUT_STEP_S = 0.001
OPTIMIZER_STEP_S = 0.004
"""The fixed cost of a PPO update that FLOPs do not see (:func:`update_overhead_seconds`):
per update (GAE, the weights' NaN check, the metrics.csv row and the job's progress point),
per rollout time step (one observe, actor + critic forward and env step of all B envs:
Python and torch dispatch, whatever B), per optimizer step (a minibatch's forward, backward,
two gradient clips, Adam step and loss read-outs). Measured on this project's 2-core CPU on
2026-12-04 while another benchmark held both cores (load ~3), one torch thread, a 4 x 4 grid
of one ODMTL agent (FLOPs ~0.01 ms per update, negligible), ``num_envs`` 1, median of
60-400 updates, each update as a job runs it (``collect``, ``update``, the metrics row and
progress point, no checkpoint)::

    .venv/bin/python benchmarks/update_overhead.py

    horizon 1,  1 epoch,  1 minibatch:     7.4 ms  (1 rollout step, 1 optimizer step)
    horizon 16, 1 epoch,  1 minibatch:    24.1 ms  -> 1.1 ms per rollout step
    horizon 64, 1 epoch,  1 minibatch:    70.9 ms  -> 1.0 ms per rollout step
    horizon 16, 4 epochs, 16 minibatches: 289.7 ms -> 4.2 ms per optimizer step (64 vs 1)

so ~1 ms per rollout step, ~4 ms per optimizer step and ~2 ms for the rest (7.4 - 1.1 - 4.2).
A checkpoint (fsynced) cost another ~31 ms; a job writes one every CHECKPOINT_EVERY updates
but at most one per CHECKPOINT_INTERVAL_S seconds (``workers/daemon/job.py``), so where this
term matters (tiny updates) checkpoints are not per update and are left out. On an idle core
the figures are lower: an over-estimate, on the safe side of the deadline check."""
F32, I64 = 4, 8


@dataclass(frozen=True)
class ResourceEstimate:
    memory_bytes: int
    """Estimated peak resident memory of one training process."""
    memory_parts: dict[str, int]
    """memory_bytes by part (env, observations, rollout, networks, optimizer, update, process)."""
    flops_per_step: int
    """Estimated floating-point operations per env step (rollout + update + env, plus the
    evaluations' share when the spec keeps the best evaluated policy)."""
    env_steps: int
    """Env steps the budget allows (steps, or minutes at the estimated rate)."""
    hours: float
    """Estimated wall-clock hours of one worker (capped by budget.minutes)."""

    @property
    def flops(self) -> int:
        return self.flops_per_step * self.env_steps


def lenet_params(in_shape: tuple[int, int, int], outputs: int) -> int:
    """Parameters of networks.LeNet (Table 3.1) for ``in_shape`` (C, H, W) and ``outputs``."""
    c, h, w = in_shape
    flat = 16 * math.ceil(h / 2) * math.ceil(w / 2)
    return (
        (c * 8 * 9 + 8)
        + (8 * 16 * 9 + 16)
        + (flat * 32 + 32)
        + (32 * 16 + 16)
        + (16 * outputs + outputs)
    )


def lenet_flops(in_shape: tuple[int, int, int], outputs: int) -> int:
    """Multiply-adds x 2 of one LeNet forward pass."""
    c, h, w = in_shape
    h2, w2 = math.ceil(h / 2), math.ceil(w / 2)
    return 2 * (
        9 * c * 8 * h * w + 9 * 8 * 16 * h2 * w2 + 16 * h2 * w2 * 32 + 32 * 16 + 16 * outputs
    )


def lenet_activations(in_shape: tuple[int, int, int], outputs: int) -> int:
    """Floats one sample keeps for the backward pass (layer outputs incl. the logits)."""
    c, h, w = in_shape
    h2, w2 = math.ceil(h / 2), math.ceil(w / 2)
    return (
        c * h * w + 8 * h * w * 2 + 8 * h2 * w2 + 16 * h2 * w2 * 2 + 32 * 2 + 16 * 2 + outputs * 3
    )


def _policy_outputs(env: Any, obs: Any) -> tuple[int, int]:
    """Actor samples per env step and actor outputs: CMTL ranks the joint action (A**N)."""
    a = env.moves + 1
    return (1, a**env.agents) if obs.kind == "cmtl" else (env.agents, a)


def observer_bytes(env: Any, obs: Any, num_envs: int) -> int:
    """One observation batch of ``num_envs`` envs, the policy mask of a step (joint: A**N per
    env) and its logits, and the observer's own state (belief filter, route distances)."""
    b, c = num_envs, env.rows * env.cols
    np_, ap = _policy_outputs(env, obs)
    layout = channel_layout(env, obs)
    actor_in, critic_in = math.prod(layout.actor_shape), math.prod(layout.critic_shape)
    window = obs.window * obs.window if obs.kind == "odmtl" else 0
    out = b * (np_ * actor_in + critic_in) * F32 + c * window * F32 + b * np_ * ap * (1 + 3 * F32)
    # belief filter (workers/mdrl/belief.py): unit counts and their logs, C x C float64 shared
    # without walls, per env float32 with walls; the (B, K, C) log-likelihood of a step
    if obs.belief:
        gains = 2 * c * c * (b * F32 if env.walls[1] > 0 else 8)
        out += gains + 3 * b * 8 * c * 8
    if obs.route:  # BFS steps from the posterior's top cells, int32 (observations.py)
        out += b * ROUTE_CELLS * c * 4
    return out


def expert_bytes(task: Any, env: Any, obs: Any, num_envs: int) -> tuple[int, int]:
    """An MEDC expert trained on ``env`` with observation ``obs`` (its card) guiding a run of
    EnvSpec ``task`` on ``num_envs`` envs: (held for the whole run: its actor and critic
    weights and the observer the adapter builds for it on the task's grid; one forward pass of
    its actor over every env's agents: the layer outputs, inference keeps no gradients)."""
    on_task = laid_on_task(env, task)
    own = dataclasses.replace(on_task, agents=env.agents, moves=env.moves)
    layout = channel_layout(own, obs)
    samples, outputs = _policy_outputs(env, obs)
    if obs.kind != "cmtl":
        samples = task.agents  # the adapter ranks each task agent's action
    params = lenet_params(layout.actor_shape, outputs) + lenet_params(layout.critic_shape, 1)
    forward = num_envs * samples * lenet_activations(layout.actor_shape, outputs) * F32
    return params * F32 + observer_bytes(on_task, obs, num_envs), forward


def walls_cae_bytes(card: dict[str, Any], num_envs: int) -> int:
    """The walls CAE of ``observation.walls_embedding`` (its card as ``cae.save_cae`` writes
    it: grid, embedding d, architecture.channels): the whole file's weights (the encoder and
    its mirrored decoder) and one encoding of every env's walls map (a reset embeds the new
    layouts)."""
    rows, cols = (int(g) for g in card["grid"])
    d = int(card["embedding"])
    channels = [int(ch) for ch in card["architecture"]["channels"]]
    kernels, acts, c_in, h, w = 0, rows * cols, 1, rows, cols
    for ch in channels:  # 3x3 stride-2 convolutions; the decoder's transposed ones mirror them
        h, w = math.ceil(h / 2), math.ceil(w / 2)
        kernels += c_in * ch * 9
        acts += ch * h * w
        c_in = ch
    code = c_in * h * w
    biases = sum(channels) + sum(channels[:-1]) + 1 + d + code  # decoder ends in one channel
    params = 2 * kernels + 2 * code * d + biases  # fc code -> d and d -> code
    return params * F32 + num_envs * (acts + d) * F32


def estimate(
    spec: TrainingSpec,
    experts: Sequence[tuple[Any, Any]] = (),
    walls_cae: dict[str, Any] | None = None,
) -> ResourceEstimate:
    """Memory and compute of training ``spec`` (see the module docstring); ``experts`` are
    the (EnvSpec, ObservationSpec) of the MEDC experts' cards and ``walls_cae`` the card of
    the walls CAE, when known (their parts are 0 otherwise)."""
    env, obs, ppo = spec.env, spec.observation, spec.ppo
    b, n, c, a = ppo.num_envs, env.agents, env.rows * env.cols, env.moves + 1
    t = ppo.rollout_steps
    np_, ap = _policy_outputs(env, obs)  # actor samples per env step, actor outputs
    layout = channel_layout(env, obs)
    actor_in = math.prod(layout.actor_shape)
    critic_in = math.prod(layout.critic_shape)

    # env: static geometry (C x C distances and gains, built at start) + per-env state
    geometry = c * c * (8 + 4 + 8 + 8) + c * a * I64
    per_env = c * (1 + 4 + 8 + 4 + 4 + a * I64) + n * (I64 + HISTORY * I64 + a) + 7 * I64
    env_bytes = geometry + 2 * b * per_env  # x2: the arrays a reset builds for the new episodes
    obs_bytes = observer_bytes(env, obs, b)
    # per step: actor and critic maps, masks, actions + log-probs, value + reward + done (9 B)
    # and the policy-loss weight (4 B, rollout.RolloutBuffer.weights)
    rollout = t * b * (np_ * actor_in * F32 + critic_in * F32 + np_ * ap + np_ * (I64 + F32) + 13)
    params = lenet_params(layout.actor_shape, ap) + lenet_params(layout.critic_shape, 1)
    networks = params * F32 * 2  # weights + gradients
    optimizer = params * F32 * 2  # Adam's two moments
    minibatch = math.ceil(t * b / ppo.num_minibatches)
    update = (
        minibatch
        * (
            np_ * lenet_activations(layout.actor_shape, ap)
            + lenet_activations(layout.critic_shape, 1)
        )
        * F32
        * 2  # activations and their gradients
    )
    # each expert keeps its weights and observer; their forward passes come one at a time
    guides = [expert_bytes(env, e, o, b) for e, o in experts]
    parts = {
        "env": env_bytes,
        "observations": obs_bytes,
        "rollout": rollout,
        "networks": networks,
        "optimizer": optimizer,
        "update": update,
        "process": PROCESS_BASE_BYTES,
        "experts": sum(h for h, _ in guides) + max((f for _, f in guides), default=0),
        "walls_cae": 0 if walls_cae is None else walls_cae_bytes(walls_cae, b),
    }

    per_step = flops_per_step(spec)
    step_s = _step_seconds(spec)
    final_s = final_evaluation_seconds(spec)
    overhead, batch = update_overhead_seconds(spec), spec.ppo.batch_steps
    if spec.budget.steps is not None:
        steps = spec.budget.steps
        updates = -(-steps // batch)  # the last, shortened update pays its overhead too
        hours = (steps * step_s + final_s + updates * overhead) / 3600
        if spec.budget.minutes is not None:
            hours = min(hours, spec.budget.minutes / 60)
    else:  # a time budget keeps the final evaluation's time (train.Trainer._no_time_for_another)
        assert spec.budget.minutes is not None
        hours = spec.budget.minutes / 60
        step_s += overhead / batch  # an update's overhead over its steps
        steps = max(0, int((hours * 3600 - final_s) / step_s))
    return ResourceEstimate(sum(parts.values()), parts, per_step, steps, hours)


def final_evaluation_flops(spec: TrainingSpec) -> int:
    """FLOPs of a job's final greedy evaluation (JOB_EVAL_EPISODES episodes of at most
    max_steps steps: actor passes and env work), paid once after the last update."""
    return JOB_EVAL_EPISODES * spec.env.max_steps * _greedy_step_flops(spec)


def update_seconds(spec: TrainingSpec) -> float:
    """Estimated seconds of one PPO update (its rollout of ``batch_steps`` env steps and its
    epochs: their FLOPs and CMTL's joint actions, plus :func:`update_overhead_seconds`) on one
    reference thread: a time budget is checked between updates, so a worker whose deadline
    leaves less than this cannot stop in time."""
    return (_step_seconds(spec) * spec.ppo.batch_steps + update_overhead_seconds(spec))


def joint_action_seconds(spec: TrainingSpec) -> float:
    """Seconds per greedy env step of CMTL's passes over its A**N joint actions
    (JOINT_ACTION_S each; 0 for the per-agent kinds)."""
    _, outputs = _policy_outputs(spec.env, spec.observation)
    return JOINT_ACTION_S * outputs if spec.observation.kind == "cmtl" else 0.0


def _step_seconds(spec: TrainingSpec) -> float:
    """Seconds of one training env step on one reference thread, without the per-update
    overhead: its FLOPs (``flops_per_step``) and CMTL's joint actions in the rollout and,
    forward and backward, in each learning epoch."""
    joint = joint_action_seconds(spec) * (1 + 3 * spec.ppo.update_epochs)
    return flops_per_step(spec) / reference_flops_per_s() + joint


def optimizer_steps(spec: TrainingSpec) -> int:
    """Minibatch optimizer steps of one full update (``Trainer.update``: ``update_epochs``
    passes over ``batch_steps`` samples in minibatches of ceil(m / num_minibatches))."""
    ppo = spec.ppo
    m = ppo.batch_steps
    return ppo.update_epochs * math.ceil(m / math.ceil(m / ppo.num_minibatches))


def update_overhead_seconds(spec: TrainingSpec) -> float:
    """The cost of one PPO update that its FLOPs do not count (measured: UPDATE_FIXED_S,
    ROLLOUT_STEP_S per rollout time step, OPTIMIZER_STEP_S per optimizer step): what an
    update of a few env steps costs, whatever its arithmetic."""
    return (UPDATE_FIXED_S + ROLLOUT_STEP_S * spec.ppo.rollout_steps
            + OPTIMIZER_STEP_S * optimizer_steps(spec))


def final_evaluation_seconds(spec: TrainingSpec) -> float:
    """Estimated seconds of a job's final greedy evaluation on one reference thread: it runs
    after the last update however little time is left (``Trainer.train``), so a worker whose
    deadline cannot hold it delivers late. Its FLOPs, plus ROLLOUT_STEP_S per time step of
    each chunk of episodes stepped together (``evaluate.default_batch``: the Python and torch
    dispatch of an observe, actor pass and env step, which a small net's FLOPs do not show)."""
    batch = default_batch(spec.env, JOB_EVAL_EPISODES)
    chunks, together = -(-JOB_EVAL_EPISODES // batch), max(1, STEP_ENVS // batch)
    dispatches = -(-chunks // together) * spec.env.max_steps
    joint_s = joint_action_seconds(spec) * JOB_EVAL_EPISODES * spec.env.max_steps
    return (final_evaluation_flops(spec) / reference_flops_per_s() + joint_s
            + ROLLOUT_STEP_S * dispatches)


LOG_BYTES_PER_UPDATE = 600
"""Bytes one PPO update adds to a job's logs that grow for its whole run: a ``metrics.csv`` row
and a ``progress.jsonl`` line (~285 B together, measured 2026-12-04), doubled for wider
numbers. Checkpoints are overwritten; these are not."""
FASTEST_UPDATE_FRACTION = 0.25
"""A time budget's updates are counted at this fraction of :func:`update_seconds`: a machine
up to 4x quicker than the estimate runs that many more of them."""


def max_updates(spec: TrainingSpec, seconds: float | None = None) -> int:
    """Most PPO updates a job of ``spec`` may run: its step budget's, and no more than fit in
    its time budget or ``seconds`` (what its deadline leaves) at FASTEST_UPDATE_FRACTION of
    :func:`update_seconds` each."""
    bounds = []
    if spec.budget.steps is not None:
        bounds.append(-(-spec.budget.steps // spec.ppo.batch_steps))
    times = [t for t in (None if spec.budget.minutes is None else spec.budget.minutes * 60.0,
                         seconds) if t is not None]
    if times:
        fastest = update_seconds(spec) * FASTEST_UPDATE_FRACTION
        bounds.append(int(max(0.0, min(times)) / fastest) + 1)
    return min(bounds)


def log_bytes(spec: TrainingSpec, seconds: float | None = None) -> int:
    """Disk a job of ``spec`` may fill with its logs (LOG_BYTES_PER_UPDATE per update of
    :func:`max_updates`): a spec of one env step per update runs ~300 updates a second,
    ~50 GB of logs in a week, which no memory or time check sees."""
    return LOG_BYTES_PER_UPDATE * max_updates(spec, seconds)


def worker_hours(spec: TrainingSpec) -> float:
    """Estimated hours one worker spends on ``spec`` (what a minimum payment per
    worker-hour is charged on)."""
    return estimate(spec).hours


def flops_per_step(spec: TrainingSpec) -> int:
    """FLOPs of one env step: the rollout's forward passes, forward + backward (~3x) per update
    epoch, and the env/observer work (maps over the C cells, ODMTL downsizing)."""
    env, obs = spec.env, spec.observation
    np_, ap = _policy_outputs(env, obs)
    layout = channel_layout(env, obs)
    forward = np_ * lenet_flops(layout.actor_shape, ap) + lenet_flops(layout.critic_shape, 1)
    training = forward * (1 + 3 * spec.ppo.update_epochs) + _env_flops(spec)
    if spec.selection.keep_best is None:
        return training
    # selection.keep_best: greedy evaluations (actor only) every eval_every updates, each as
    # long as the final one, spread over the env steps of training between them
    evaluation = final_evaluation_flops(spec)
    between = spec.selection.eval_every * spec.ppo.batch_steps
    return training + -(-evaluation // between)


def _env_flops(spec: TrainingSpec) -> int:
    """FLOPs of the env and observer per env step (maps over the C cells, ODMTL downsizing,
    the belief filter)."""
    env, obs = spec.env, spec.observation
    c = env.rows * env.cols
    np_, ap = _policy_outputs(env, obs)
    window = obs.window * obs.window if obs.kind == "odmtl" else 1
    flops = 20 * c + 50 * env.agents + 2 * np_ * c * window + np_ * ap
    if obs.belief:  # two (C,) x (C, C) products per env step (belief.py), then K-way logsumexp
        flops += 4 * c * c + 30 * c
    return flops


def _greedy_step_flops(spec: TrainingSpec) -> int:
    """FLOPs of one greedy env step: the actor's forward passes and the env/observer work."""
    env, obs = spec.env, spec.observation
    np_, ap = _policy_outputs(env, obs)
    return np_ * lenet_flops(channel_layout(env, obs).actor_shape, ap) + _env_flops(spec)


@cache
def reference_flops_per_s() -> float:
    """FLOPs/s of one training thread, from REFERENCE_PRESET's measured env steps/s. That
    rate includes each update's overhead (:func:`update_overhead_seconds`, ~14% of the
    preset's 8,192-step update), taken out here so it is not counted twice."""
    from workers.mdrl.presets import get_preset

    p = get_preset(REFERENCE_PRESET)
    doc = {
        "env": {"rows": p.env.rows, "cols": p.env.cols, "agents": p.env.agents},
        "observation": REFERENCE_OBSERVATION,
        "algorithm": {"preset": REFERENCE_PRESET},
        "budget": {"minutes": 60},  # the preset's own batch (a tiny step budget shrinks it)
    }
    ref = TrainingSpec.from_dict(doc)
    batch = ref.ppo.batch_steps
    compute_s = batch / REFERENCE_STEPS_PER_S - update_overhead_seconds(ref)
    return float(flops_per_step(ref) * batch / compute_s)
