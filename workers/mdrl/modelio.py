"""Model files: `model.safetensors` (actor + critic weights) and `model.json` (the card).

The card says what the model is for and how to rebuild it: env spec, observation spec,
architecture (Table 3.1 and parameter counts), action space, training config, metrics and
code version. `load_model(dir)` rebuilds a ready-to-act greedy policy from safetensors + JSON
only (never pickle).

A model trained with a walls embedding (Ch. 4, ``ObservationSpec.walls_embedding``) carries
its frozen CAE encoder: weights under ``walls_encoder.*`` in the same safetensors file, and
``card["walls_encoder"]`` (grid, d, channels, weight digest, the directory it came from). So
the two files stay self-contained: a model fetched by CID acts without the CAE directory.
"""

from __future__ import annotations

import datetime as _dt
import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from workers.mdrl.rollout import GreedySelector, PolicyHead, policy_step
from workers.mdrl.weightsfile import MAX_WEIGHTS_BYTES, WeightsFileError, check_weights_file

MAX_CARD_BYTES = 1 << 20
"""Bound on a card read here (``backend.store.bundle.MAX_CARD_BYTES``, the bound wherever one
is read; not imported: the core does not depend on the platform)."""
CARD_FORMAT = "drlaas-model/1"
WEIGHTS = "model.safetensors"
CARD = "model.json"
ENCODER_PREFIX = "walls_encoder."
ARCHITECTURE = ("Table 3.1 LeNet-like CNN, same body for actor and critic: conv3x3x8 (pad 1) "
                "ReLU -> maxpool 2x2 stride 2 (ceil) -> conv3x3x16 (pad 1) ReLU -> flatten -> "
                "fc32 ReLU -> fc16 ReLU -> out (actor: masked softmax over actions; critic: "
                "scalar value)")


class GreedyPolicy:
    """A trained actor acting greedily (Alg. 3.4): the Policy interface (reset, act) of the core.

    CLDE models run the shared actor once per agent on that agent's observation; CMTL models
    pick one joint action and decode it into per-agent actions.
    """

    def __init__(self, agent: Any, observer: Any, head: PolicyHead):
        self.agent, self.observer, self.head = agent, observer, head
        self._select = GreedySelector()

    def reset(self, env: Any) -> None:
        """Nothing to reset: observations carry the episode's memory."""

    @torch.inference_mode()
    def act(self, env: Any) -> np.ndarray:
        """Greedy valid actions int64 (B, N) for the current state of `env`."""
        actor_obs, _ = self.observer.observe(env)
        mask = torch.from_numpy(np.ascontiguousarray(self.head.policy_mask(env.action_mask())))
        actions, _ = policy_step(self.agent, torch.as_tensor(actor_obs), mask, self._select, env)
        return self.head.env_actions(actions.numpy())

    def action_probs(self, env: Any) -> np.ndarray:
        """Policy probabilities (B, Np, Ap) over valid actions (for experts / analysis)."""
        from workers.mdrl.ppo import masked_log_probs

        with torch.inference_mode():
            actor_obs, _ = self.observer.observe(env)
            obs = torch.as_tensor(actor_obs)
            mask = torch.from_numpy(np.ascontiguousarray(self.head.policy_mask(env.action_mask())))
            b, n = obs.shape[:2]
            flat_mask = mask.reshape(b * n, -1)
            logits = self.agent.logits(obs.reshape(b * n, *obs.shape[2:]), flat_mask)
            return masked_log_probs(logits, flat_mask).exp().reshape(b, n, -1).numpy()


def code_version() -> dict[str, Any]:
    """Package version and, if this is a git checkout, the commit (and whether it is dirty)."""
    info: dict[str, Any] = {"package": "drlaas"}
    try:
        from importlib.metadata import version

        info["version"] = version("drlaas")
    except Exception:  # not installed (run from a source tree)
        info["version"] = None
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                                text=True, timeout=5)
        info["git_commit"] = commit.stdout.strip() if commit.returncode == 0 else None
        if info["git_commit"]:
            dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--",
                                    "workers"], capture_output=True, text=True, timeout=5)
            info["git_dirty"] = bool(dirty.stdout.strip())
    except (OSError, subprocess.SubprocessError):
        info["git_commit"] = None
    return info


def _count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


def save_model(path: str | Path, agent: torch.nn.Module, env_spec: Any, obs_spec: Any,
               ppo: Any, *, metrics: dict[str, Any] | None = None, observer: Any = None,
               training: dict[str, Any] | None = None) -> Path:
    """Write `model.safetensors` + `model.json` into directory `path`; returns the directory."""
    from workers.mdrl.observations import make_observer

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    if observer is None:
        observer = make_observer(env_spec, obs_spec)
    head = PolicyHead(env_spec.num_actions, env_spec.agents, joint=bool(observer.joint_actions))
    tensors = {k: v.detach().contiguous().clone() for k, v in agent.state_dict().items()}
    embedder = getattr(observer, "embedder", None)
    encoder = {} if embedder is None else {
        ENCODER_PREFIX + k: v.detach().contiguous().clone()
        for k, v in embedder.encoder.state_dict().items()}
    save_file({**tensors, **encoder}, str(path / WEIGHTS), metadata={"format": CARD_FORMAT})
    card = {
        "format": CARD_FORMAT,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "model": obs_spec.kind.upper(),
        "env": env_spec.to_dict(),
        "observation": {**obs_spec.to_dict(),
                        "actor_shape": list(observer.actor_shape),
                        "critic_shape": list(observer.critic_shape)},
        "architecture": {
            "description": ARCHITECTURE,
            "actor_parameters": _count(agent.actor),
            "critic_parameters": _count(agent.critic),
            "total_parameters": _count(agent),
            "tensors": {k: list(v.shape) for k, v in tensors.items()},
        },
        "action_space": {
            "per_agent_actions": env_spec.num_actions,
            "moves": env_spec.moves,
            "agents": env_spec.agents,
            "joint": head.joint,
            "policy_actions": head.policy_actions,
            "execution": ("one joint actor, index = sum a_i * A**(N-1-i)" if head.joint
                          else "shared actor applied to each agent's observation (CLDE)"),
        },
        "training": {"ppo": ppo.to_dict() if hasattr(ppo, "to_dict") else dict(ppo),
                     **(training or {})},
        "metrics": _jsonable(metrics or {}),
        "code": code_version(),
    }
    if embedder is not None:
        card["walls_encoder"] = embedder.card
    (path / CARD).write_text(json.dumps(card, indent=1))
    return path


def model_file(path: str | Path, name: str) -> Path:
    """``path/name``, a regular file and no symlink: a model directory fetched or unpacked from
    elsewhere must not make a loader read (or a size bound check) another file of this host."""
    file = Path(path) / name
    if file.is_symlink():
        raise ValueError(f"{file}: a symlink; a model directory holds its files themselves")
    if not file.is_file():
        raise FileNotFoundError(f"not a model directory {path}: no {name}")
    return file


def check_card_bounds(card: dict[str, Any], *, task_grid: bool = True) -> None:
    """The task-spec bounds on a card's env and observation (grid, agents, window,
    max_steps, idle_limit ...): a card is as untrusted as a spec, and an unbounded one (a
    10^5 x 10^5 grid, episodes of 10^9 steps) exhausts memory or never ends an evaluation.
    ``task_grid=False`` (a model on this machine, which may be trained on a long thin grid)
    bounds the grid by EnvSpec's cell count instead of the task spec's side. SpecError (a
    ValueError) names the field; TypeError/KeyError for a card of the wrong shape."""
    from workers.mdrl.observations import ObservationSpec
    from workers.mdrl.spec import EnvSpec
    from workers.mdrl.specfields import check_object
    from workers.mdrl.trainingspec import ENV_RULES, OBSERVATION_RULES, parse_env

    env = card["env"]
    if task_grid or not isinstance(env, dict):
        parse_env(env, "env")
    else:
        side = ("rows", "cols")
        check_object({k: v for k, v in env.items() if k not in side},
                     {k: rule for k, rule in ENV_RULES.items() if k not in side}, "env")
        EnvSpec.from_dict(env)
    obs = card_observation(card)
    embedding = obs.pop("walls_embedding", None)  # informative: the file holds the encoder
    if embedding is not None and not (isinstance(embedding, str) and len(embedding) <= 600):
        raise ValueError("observation.walls_embedding: expected a CAE reference or null")
    check_object(obs, OBSERVATION_RULES, "observation")
    ObservationSpec.from_dict({**obs, "walls_embedding": embedding})
    if not isinstance(card["observation"].get("actor_shape"), list):
        raise TypeError("observation.actor_shape must be a list")


def load_card(path: str | Path) -> dict[str, Any]:
    """Read and check `model.json` of a model directory: at most MAX_CARD_BYTES, within the
    task-spec bounds (``check_card_bounds``)."""
    card_path = model_file(path, CARD)
    with card_path.open("rb") as fh:
        raw = fh.read(MAX_CARD_BYTES + 1)
    if len(raw) > MAX_CARD_BYTES:
        raise ValueError(f"{card_path}: more than {MAX_CARD_BYTES} bytes, not a model card")
    try:
        card = json.loads(raw)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, UnicodeDecodeError
        raise ValueError(f"{card_path}: not JSON ({type(exc).__name__}: {exc})") from None
    if not isinstance(card, dict):
        raise ValueError(f"{card_path}: a model card is a JSON object, got "
                         f"{type(card).__name__}")
    if card.get("format") != CARD_FORMAT:
        raise ValueError(f"{card_path}: unknown model format {card.get('format')!r}")
    if "kind" in card:
        raise ValueError(f"{card_path}: a {card['kind']!r} model, not a policy (a walls CAE "
                         "loads with cae.load_cae)")
    for section in ("env", "observation"):
        if not isinstance(card.get(section), dict):
            raise ValueError(f"{card_path}: the card has no {section!r} section (an object), "
                             f"got {card.get(section)!r}")
    try:
        check_card_bounds(card, task_grid=False)
    except (KeyError, TypeError, ValueError, ArithmeticError) as exc:
        raise ValueError(f"{card_path}: {exc} (bounds of a task spec)") from None
    return card


def load_weights(path: str | Path) -> dict[str, torch.Tensor]:
    """The tensors of a model directory's ``model.safetensors``; ValueError naming the model
    when the file is not readable safetensors or a weight is NaN or infinite (a diverged
    run's model acts on garbage)."""
    file = model_file(path, WEIGHTS)
    size = file.stat().st_size
    if size > MAX_WEIGHTS_BYTES:  # read whole before the key check: 256 MB cost 1.25 GB of RAM
        raise ValueError(f"{file}: {size} bytes, more than a model's weights may be "
                         f"({MAX_WEIGHTS_BYTES} bytes)")
    try:
        check_weights_file(file)  # the header alone: a pickle, a bad dtype, an empty tensor
    except WeightsFileError as exc:
        raise ValueError(f"{file}: not a readable safetensors file ({exc})") from None
    try:
        tensors = load_file(str(file))
    except SafetensorError as exc:
        raise ValueError(f"{file}: not a readable safetensors file ({exc})") from None
    ints = sorted(k for k, v in tensors.items() if not v.is_floating_point())
    if ints:  # every weight of a policy or its walls encoder is floating point
        raise ValueError(f"{file}: weights must be floating point; {len(ints)} tensor(s) are "
                         f"{tensors[ints[0]].dtype}, e.g. {ints[0]!r}")
    broken = sorted(k for k, v in tensors.items()
                    if v.is_floating_point() and not bool(torch.isfinite(v).all()))
    if broken:
        raise ValueError(f"{file}: the model's weights hold NaN/inf ({len(broken)} tensor(s), "
                         f"e.g. {broken[0]!r}): a diverged run's model, refused")
    return tensors


SHAPE_KEYS = ("actor_shape", "critic_shape")
"""What a card's ``observation`` adds to the ObservationSpec fields (the built input shapes)."""


def card_observation(card: dict[str, Any]) -> dict[str, Any]:
    """The ObservationSpec fields of a card's ``observation`` section (without the shapes)."""
    return {k: v for k, v in card["observation"].items() if k not in SHAPE_KEYS}


def card_specs(card: dict[str, Any]) -> tuple[Any, Any]:
    """The (EnvSpec, ObservationSpec) a policy card describes, checked against the task-spec
    bounds (what ``resources.expert_bytes`` sizes an expert by); ValueError (SpecError is
    one), TypeError or KeyError for a card that does not describe them."""
    from workers.mdrl.observations import ObservationSpec
    from workers.mdrl.trainingspec import parse_env

    return parse_env(card["env"], "env"), ObservationSpec.from_dict(card_observation(card))


def load_model(path: str | Path) -> GreedyPolicy:
    """Rebuild the greedy policy of a model directory (safetensors + JSON, no pickle)."""
    from workers.mdrl.networks import ActorCritic
    from workers.mdrl.observations import ObservationSpec, make_observer
    from workers.mdrl.spec import EnvSpec

    path = Path(path)
    card = load_card(path)
    env_spec = EnvSpec.from_dict(card["env"])
    obs_spec = ObservationSpec.from_dict(card_observation(card))
    tensors = load_weights(path)
    encoder = {k[len(ENCODER_PREFIX):]: tensors.pop(k) for k in list(tensors)
               if k.startswith(ENCODER_PREFIX)}
    embedder = None
    if obs_spec.walls_embedding:
        from workers.mdrl.cae import WallsEmbedder, encoder_from_tensors

        if "walls_encoder" not in card or not encoder:
            raise ValueError(f"{path}: the observation uses a walls embedding but the model "
                             "file carries no walls encoder")
        info = card["walls_encoder"]
        embedder = WallsEmbedder(encoder_from_tensors(info, encoder), info.get("source"))
    observer = make_observer(env_spec, obs_spec, walls_encoder=embedder)
    head = PolicyHead(env_spec.num_actions, env_spec.agents, joint=bool(observer.joint_actions))
    agent = ActorCritic(observer, head.policy_actions)
    try:
        agent.load_state_dict(tensors)
    except RuntimeError as exc:  # torch's text lists every tensor: name the cause, then one
        first = next((line.strip() for line in str(exc).splitlines()
                      if "size mismatch" in line or "key(s)" in line), str(exc)[:300])
        raise ValueError(f"{path}: the weights do not fit the network its card describes "
                         "(env and observation: the card was edited or is another model's); "
                         f"{first}") from None
    agent.eval()
    policy = GreedyPolicy(agent, observer, head)
    policy.card = card  # type: ignore[attr-defined]
    policy.env_spec = env_spec  # type: ignore[attr-defined]
    return policy


def load_initial_weights(agent: torch.nn.Module, path: str | Path, obs_spec: Any,
                         observer: Any, agents: int, num_actions: int) -> dict[str, Any]:
    """Copy a model's actor and critic weights into ``agent`` (fine-tuning a shared model).

    The model must read the same observation (every ``ObservationSpec`` field: same planes,
    window, readings, belief ...) for the same team size and action set; the env may differ
    otherwise (walls, reward, grid under ODMTL), which is what fine-tuning is for. A walls
    encoder in the file is not copied: the run's observer has its own. Returns what the
    card records of the start (path and weight digest)."""
    import hashlib

    path = Path(path)
    card = load_card(path)
    theirs = card_observation(card)
    ours = obs_spec.to_dict()
    differ = sorted(k for k in set(theirs) | set(ours) if theirs.get(k) != ours.get(k))
    if differ:
        raise ValueError(f"init_from {str(path)!r}: its observation differs in {differ} "
                         f"(model: {[theirs.get(k) for k in differ]}, this run: "
                         f"{[ours.get(k) for k in differ]})")
    for part in SHAPE_KEYS:  # e.g. wall maps come with walls in the env
        theirs_shape = card["observation"].get(part)
        if theirs_shape != list(getattr(observer, part)):
            raise ValueError(f"init_from {str(path)!r}: its {part.split('_')[0]} reads inputs of "
                             f"shape {theirs_shape}, this run's are "
                             f"{list(getattr(observer, part))}")
    space = card.get("action_space", {})
    if (space.get("agents"), space.get("per_agent_actions")) != (agents, num_actions):
        raise ValueError(f"init_from {str(path)!r}: a model for {space.get('agents')} agent(s) "
                         f"and {space.get('per_agent_actions')} actions, this run has {agents} "
                         f"and {num_actions}")
    tensors = {k: v for k, v in load_weights(path).items()
               if not k.startswith(ENCODER_PREFIX)}
    own = agent.state_dict()
    wrong = sorted(k for k in set(own) | set(tensors)
                   if k not in own or k not in tensors or own[k].shape != tensors[k].shape)
    if wrong:
        raise ValueError(f"init_from {str(path)!r}: weights do not fit this network ({wrong})")
    agent.load_state_dict(tensors)
    digest = hashlib.sha256((path / WEIGHTS).read_bytes()).hexdigest()
    return {"ref": str(path), "weights_sha256": digest,
            "env_steps": card.get("training", {}).get("env_steps")}


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in d.items():
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, float) and v != v:  # NaN is not JSON
            v = None
        out[k] = v
    return out
