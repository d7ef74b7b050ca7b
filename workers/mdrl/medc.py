"""Demonstration Cloning (DC, Alg. 4.1) and Multi-Expert DC (MEDC, Alg. 5.1) as an action
selector for the trainer (``rollout.ActionSelector``).

Per episode (drawn at ``episode_start`` from a seeded generator): with probability R_E the
episode is guided by one expert, picked by roulette wheel over R_S = QoS_i / sum QoS (Table
5.3); otherwise the agents act on their own. In a guided episode the expert ranks every
agent's actions from the same state, and each agent takes the best-ranked action whose
probability under its OWN policy exceeds l (Alg. 5.1 lines 10-14); an agent with no such
action samples its own (the issue's fallback; Alg. 4.1 line 10 would take a zeroed argmax).
PPO then learns from that experience with the team's reward and the agent's own
log-probability of the action taken (``rollout.policy_step`` gathers it from the learner's
distribution), which is what keeps DC on-policy: the threshold l keeps taken actions probable.

Alg. 5.1 draws the roulette wheel at line 8, inside the step loop; we draw it once per
episode with ExpertCheck (line 3), as the thesis' text describes it ("one of the experts is
selected ... to guide the episode"), so an episode follows one consistent expert. DC (Alg.
4.1) is the one-expert case with E in place of R_E.

Defaults: l = 0.05 (Tables 4.1 and 5.3); the rate is E = 0.2 with one expert (Table 4.1) and
R_E = 0.1 with several (Table 5.3) unless given. Alg. 5.1 keeps R_E fixed; ``rate_end`` (ours)
moves it linearly from ``rate`` to ``rate_end`` over a step budget (the trainer reports its
progress through ``set_progress``), so that experts which helped the team start stop steering
it once it has outgrown them.

Sampling (unguided agents and the fallback) is the trainer's own ``SampleSelector`` draw with
the trainer's generator (``bind``), taken for every agent at every step, so that the random
stream does not depend on the experts: with rate 0 training is bit-for-bit plain PPO.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from workers.mdrl.rollout import SampleSelector

DC_RATE = 0.2
"""Expert rate E of DC with one expert (Table 4.1)."""
MEDC_RATE = 0.1
"""Expert rate R_E of MEDC with several experts (Table 5.3)."""
THRESHOLD = 0.05
"""Action probability threshold l (Tables 4.1 and 5.3)."""
MAX_EXPERTS = 16
CREDIT_EMA = 0.05
"""Weight of one finished episode in the running mean episode lengths of the credit rule."""
CREDIT_MIN_EPISODES = 4
"""Episodes of an expert (and of the agents alone) before the credit rule judges it."""
CREDIT_MARGIN = 0.25
"""Credit factor clip((L_own / L_expert - 1) / CREDIT_MARGIN, 0, 1): an expert keeps its full
weight while its guided episodes are at least 1/(1 + CREDIT_MARGIN) of the agents' own length
(20% shorter), and none once they are no shorter: an expert that does not shorten episodes
only takes experience away from the agents' own policy."""
SEED_SALT = 0x4D454443  # "MEDC": the selector's stream differs from the trainer's for a seed


@dataclass(frozen=True)
class DemonstrationConfig:
    """Which experts guide a training run and how (the ``experts`` section of a config file)."""

    experts: tuple[str, ...]
    """Expert references: model directories, CIDs (resolved by the platform) or built-ins
    (``experts.BUILTINS``)."""
    qos: tuple[float, ...] = ()
    """QoS weight of each expert; R_S = QoS_i / sum QoS (Table 5.3). Empty = equal weights."""
    rate: float | None = None
    """R_E, probability that an episode is expert-guided; None = E = 0.2 for one expert
    (Table 4.1), R_E = 0.1 for several (Table 5.3)."""
    threshold: float = THRESHOLD
    """l: an agent follows the expert only on actions with probability > l under its policy."""
    credit: bool = False
    """Expert credit (ours, not in Alg. 5.1): an expert whose guided episodes run longer than
    the agents' own loses selection weight and guidance share, and PPO learns from an expert's
    episodes only once it has shown that it shortens them (``DemonstrationSelector``:
    ``credit_factors``, ``learning_weights``)."""
    rate_end: float | None = None
    """R_E at the end of the step budget, reached linearly from ``rate`` (ours; None = R_E
    fixed, Alg. 5.1). Needs a step budget (``RunConfig.total_steps``)."""

    def __post_init__(self) -> None:
        e = self.experts
        if not e or not all(isinstance(x, str) and x for x in e):
            raise ValueError(f"experts: give 1-{MAX_EXPERTS} expert references, got {list(e)}")
        if len(e) > MAX_EXPERTS:
            raise ValueError(f"experts: at most {MAX_EXPERTS}, got {len(e)}")
        if self.qos:
            if len(self.qos) != len(e):
                raise ValueError(f"expert qos: {len(self.qos)} weight(s) for {len(e)} expert(s)")
            if not all(_finite(q) and q >= 0 for q in self.qos) or sum(self.qos) <= 0:
                raise ValueError(f"expert qos: weights must be finite, >= 0 and not all 0, "
                                 f"got {list(self.qos)}")
        if self.rate is not None and not (_finite(self.rate) and 0 <= self.rate <= 1):
            raise ValueError(f"expert rate must lie in [0, 1], got {self.rate!r}")
        if self.rate_end is not None and not (_finite(self.rate_end) and 0 <= self.rate_end <= 1):
            raise ValueError(f"expert rate_end must lie in [0, 1], got {self.rate_end!r}")
        if not (_finite(self.threshold) and 0 <= self.threshold < 1):
            raise ValueError(f"expert threshold l must lie in [0, 1), got {self.threshold!r}")

    @property
    def resolved_rate(self) -> float:
        """The rate in force (see ``rate``)."""
        if self.rate is not None:
            return float(self.rate)
        return DC_RATE if len(self.experts) == 1 else MEDC_RATE

    @property
    def weights(self) -> tuple[float, ...]:
        """QoS weights with the equal default filled in."""
        return tuple(float(q) for q in self.qos) or (1.0,) * len(self.experts)

    def to_dict(self) -> dict[str, Any]:
        return {"models": list(self.experts), "qos": list(self.weights),
                "rate": self.resolved_rate, "threshold": self.threshold} | (
                    {"credit": True} if self.credit else {}) | (
                    {"rate_end": self.rate_end} if self.rate_end is not None else {})

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DemonstrationConfig:
        """From a config file's ``experts`` section: ``models`` (list), optional ``qos``,
        ``rate``, ``rate_end``, ``threshold``, ``credit``."""
        if not isinstance(d, dict):
            raise ValueError(f"config section [experts] must be a table/object, got {d!r}")
        known = {"models", "qos", "rate", "rate_end", "threshold", "credit"}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"[experts]: unknown key(s) {unknown}; known: {sorted(known)}")
        models = d.get("models")
        if not isinstance(models, list):
            raise ValueError(f"[experts] models: expected a list of references, got {models!r}")
        qos = d.get("qos") or ()
        if not isinstance(qos, (list, tuple)):
            raise ValueError(f"[experts] qos: expected a list of numbers, got {qos!r}")
        credit = d.get("credit", False)
        if not isinstance(credit, bool):
            raise ValueError(f"[experts] credit: expected true or false, got {credit!r}")
        return cls(tuple(models), tuple(qos), d.get("rate"), d.get("threshold", THRESHOLD),
                   credit, d.get("rate_end"))


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def parse_list(text: str, what: str) -> list[str]:
    """``"a,b"`` -> ``["a", "b"]`` (command-line lists); empty items are an error."""
    items = [s.strip() for s in text.split(",")]
    if not all(items):
        raise ValueError(f"{what}: empty item in {text!r}")
    return items


class DemonstrationSelector:
    """The DC / MEDC action selector (module docstring); an ``ActionSelector`` for ``Trainer``.

    ``experts``: objects with ``name``, ``scores(env, rows) -> (k, N, A)`` and ``every_step``
    (``experts.load_experts``). Attributes ``episodes`` (episodes each expert guided),
    ``own_episodes``, ``decisions`` (agent decisions in guided episodes per expert) and
    ``followed`` (how many of them took an action the expert ranked, its first eligible one) and
    ``agreed`` (how many took the expert's own first choice; the rest are where l overruled
    it) are what the card reports.
    """

    def __init__(self, experts: Sequence[Any], qos: Sequence[float] | None = None,
                 rate: float | None = None, threshold: float = THRESHOLD, seed: int = 0,
                 generator: torch.Generator | None = None, credit: bool = False,
                 rate_end: float | None = None):
        if not experts:
            raise ValueError("DemonstrationSelector needs at least one expert")
        config = DemonstrationConfig(tuple(e.name for e in experts), tuple(qos or ()), rate,
                                     threshold, credit, rate_end)
        self.config, self.experts = config, list(experts)
        self.rate, self.threshold = config.resolved_rate, float(config.threshold)
        self.progress = 0.0  # share of the step budget done (set_progress; rate_end)
        w = np.asarray(config.weights, dtype=np.float64)
        self.qos_share = w / w.sum()  # R_S = QoS_i / sum QoS
        self.wheel = np.cumsum(self.qos_share)  # roulette wheel over R_S
        self.wheel[-1] = 1.0
        self.credit = bool(config.credit)
        k = len(self.experts)
        self.steps_in_episode = np.zeros(0, dtype=np.int64)  # per env (credit rule)
        self.mean_length = np.zeros(k + 1)  # running mean episode length; index k = own
        self.judged = np.zeros(k + 1, dtype=np.int64)  # finished episodes seen per guide
        self.rng = np.random.default_rng([seed, SEED_SALT])
        self._sampler = SampleSelector(generator or torch.Generator().manual_seed(seed))
        self.current = np.full(0, -1, dtype=np.int64)  # per env: guiding expert, -1 = own
        self.weight = np.ones(0)  # per env: policy-loss weight of its episode (credit rule)
        self.episodes = np.zeros(k, dtype=np.int64)
        self.decisions = np.zeros(k, dtype=np.int64)
        self.followed = np.zeros(k, dtype=np.int64)
        self.agreed = np.zeros(k, dtype=np.int64)
        self.own_episodes = 0

    @classmethod
    def from_config(cls, config: DemonstrationConfig, task: Any, seed: int = 0,
                    generator: torch.Generator | None = None,
                    experts: Sequence[Any] | None = None) -> DemonstrationSelector:
        """The selector of ``config`` for a task (EnvSpec): its experts loaded here, or
        ``experts`` already loaded (e.g. fetched and verified by the worker daemon), with every
        setting of the config (rate, threshold, credit) carried over."""
        if experts is None:
            from workers.mdrl.experts import load_experts

            experts = load_experts(config.experts, task, seed=seed)
        return cls(experts, config.qos, config.rate, config.threshold, seed, generator,
                   config.credit, config.rate_end)

    def bind(self, generator: torch.Generator) -> None:
        """Sample with the trainer's generator (``Trainer`` calls this), so rate 0 is plain PPO."""
        self._sampler = SampleSelector(generator)

    @property
    def needs_step_budget(self) -> bool:
        """A rate schedule runs over the step budget (``Trainer.train`` refuses a run without)."""
        return self.config.rate_end is not None

    def set_progress(self, fraction: float) -> None:
        """The share of the step budget done (the trainer calls this before each rollout): with
        ``rate_end`` R_E = rate + (rate_end - rate) * fraction; without it, nothing changes."""
        self.progress = min(max(float(fraction), 0.0), 1.0)
        end = self.config.rate_end
        if end is not None:
            start = self.config.resolved_rate
            self.rate = start + (end - start) * self.progress

    # ------------------------------------------------------------------ per episode
    def episode_start(self, env_ids: np.ndarray) -> None:
        """ExpertCheck < R_E (Alg. 5.1 line 3), then the roulette wheel over R_S (line 8)."""
        env_ids = np.asarray(env_ids, dtype=np.int64)
        if not len(env_ids):
            return
        if env_ids.max() >= len(self.current):
            grown = np.full(env_ids.max() + 1, -1, dtype=np.int64)
            grown[:len(self.current)] = self.current
            self.current = grown
            steps = np.zeros(env_ids.max() + 1, dtype=np.int64)
            steps[:len(self.steps_in_episode)] = self.steps_in_episode
            self.steps_in_episode = steps
            weight = np.ones(env_ids.max() + 1)
            weight[:len(self.weight)] = self.weight
            self.weight = weight
        rate, wheel = self.rate, self.wheel
        if self.credit:
            self._judge(env_ids)
            rate, wheel = self._credited()
        check = self.rng.random(len(env_ids))
        spin = self.rng.random(len(env_ids))
        pick = np.minimum(np.searchsorted(wheel, spin, side="right"), len(wheel) - 1)
        chosen = np.where(check < rate, pick, -1)
        self.current[env_ids] = chosen
        if self.credit:
            trust = np.append(self.learning_weights(), 1.0)  # index -1 = own episode
            self.weight[env_ids] = trust[chosen]
        self.episodes += np.bincount(chosen[chosen >= 0], minlength=len(self.experts))
        self.own_episodes += int((chosen < 0).sum())

    def _judge(self, env_ids: np.ndarray) -> None:
        """Fold the episodes that just ended in ``env_ids`` into their guide's running mean."""
        ended = env_ids[self.steps_in_episode[env_ids] > 0]
        k = len(self.experts)
        for env in ended:
            g = int(self.current[env]) if self.current[env] >= 0 else k
            length = float(self.steps_in_episode[env])
            n = self.judged[g]
            alpha = 1.0 / (n + 1) if n < 1.0 / CREDIT_EMA else CREDIT_EMA  # mean, then EMA
            self.mean_length[g] += alpha * (length - self.mean_length[g])
            self.judged[g] += 1
        self.steps_in_episode[env_ids] = 0

    def credit_factors(self) -> np.ndarray:
        """Per expert, clip((L_own / L_expert - 1) / CREDIT_MARGIN, 0, 1) once both have
        CREDIT_MIN_EPISODES finished episodes (1 before): experts that do not lead the agents
        to the target faster than they manage alone fade out (faulty experts, Sec. 5.4.1; and
        every expert once the agents outgrow it)."""
        k = len(self.experts)
        factors = np.ones(k)
        if self.judged[k] < CREDIT_MIN_EPISODES:
            return factors
        own = self.mean_length[k]
        seen = self.judged[:k] >= CREDIT_MIN_EPISODES
        ratio = own / np.maximum(self.mean_length[:k], 1e-9)
        factors[seen] = np.clip((ratio[seen] - 1.0) / CREDIT_MARGIN, 0.0, 1.0)
        return factors

    def learning_weights(self) -> np.ndarray:
        """Per expert, the policy-loss weight of the episodes it guides under the credit rule:
        0 while it is on probation (fewer than CREDIT_MIN_EPISODES judged episodes, of its own
        or of the agents alone), then its credit factor. PPO thus learns only from experts that
        have shown they shorten episodes; the first guided episodes of a faulty expert, which
        the selection weight alone cannot avoid, teach the policy nothing."""
        k = len(self.experts)
        if self.judged[k] < CREDIT_MIN_EPISODES:
            return np.zeros(k)
        return np.where(self.judged[:k] >= CREDIT_MIN_EPISODES, self.credit_factors(), 0.0)

    def sample_weights(self, envs: int) -> np.ndarray | None:
        """Policy-loss weight (envs,) of each env's current step (``rollout.step_weights``):
        1 in the agents' own episodes, ``learning_weights`` in guided ones; None (all 1, Alg.
        5.1 as written) without the credit rule."""
        if not self.credit:
            return None
        return self.weight[:envs]

    def _credited(self) -> tuple[float, np.ndarray]:
        """(rate, wheel) in force under the credit rule: R_S reweighted by the credit factors,
        R_E scaled by the share of QoS weight the experts keep."""
        kept = self.qos_share * self.credit_factors()
        total = float(kept.sum())
        if total <= 0:
            return 0.0, self.wheel
        wheel = np.cumsum(kept / total)
        wheel[-1] = 1.0
        return self.rate * total, wheel

    # ------------------------------------------------------------------ per step
    def select(self, logp: torch.Tensor, mask: torch.Tensor, env: Any) -> torch.Tensor:
        """Policy actions (B, Np): own samples, replaced in guided episodes by each agent's
        best-ranked expert action with P(a) > l (Alg. 5.1 lines 9-14)."""
        own = self._sampler.select(logp, mask, env)
        b = logp.shape[0]
        if len(self.current) < b:
            raise ValueError(f"DemonstrationSelector: episode_start was not called for all "
                             f"{b} envs")
        self.steps_in_episode[:b] += 1
        current = self.current[:b]
        for i, expert in enumerate(self.experts):
            rows = np.flatnonzero(current == i)
            if not len(rows):
                if expert.every_step:  # stateful: keep it up to date with every step
                    expert.scores(env, None)
                continue
            if expert.every_step:
                scores = expert.scores(env, None)[rows]
            else:
                scores = expert.scores(env, rows)
            own = self._follow(own, logp, mask, rows, torch.from_numpy(scores), i, env)
        return own

    def _follow(self, own: torch.Tensor, logp: torch.Tensor, mask: torch.Tensor,
                rows: np.ndarray, scores: torch.Tensor, i: int, env: Any) -> torch.Tensor:
        idx = torch.from_numpy(rows)
        k, n, a = scores.shape
        joint = logp.shape[1] != n or logp.shape[2] != a
        if joint:  # CMTL: the agents' marginals of the joint policy, own joint sample decoded
            p = _marginals(logp[idx].exp(), n, a)
            agent_mask = torch.from_numpy(np.asarray(env.action_mask())[rows])
            mine = _decode(own[idx, 0], n, a)
        else:
            p, agent_mask, mine = logp[idx].exp(), mask[idx], own[idx]
        ranked = agent_mask & torch.isfinite(scores)
        eligible = ranked & (p > self.threshold)
        no = torch.full_like(scores, -torch.inf)
        best = torch.where(eligible, scores, no).argmax(-1)
        first = torch.where(ranked, scores, no).argmax(-1)
        has = eligible.any(-1)
        chosen = torch.where(has, best, mine)
        self.decisions[i] += has.numel()
        self.followed[i] += int(has.sum())
        self.agreed[i] += int((has & (best == first)).sum())
        own = own.clone()
        own[idx] = _encode(chosen, a).unsqueeze(-1) if joint else chosen
        return own

    # ------------------------------------------------------------------ state and card
    def state_dict(self) -> dict[str, Any]:
        """JSON-able state (the trainer checkpoints it): RNG, per-env guide, counters, config."""
        experts = {str(i): e.state_dict() for i, e in enumerate(self.experts)
                   if hasattr(e, "state_dict")}
        return {"config": self.config.to_dict(), "rng": self.rng.bit_generator.state,
                "current": self.current.tolist(), "episodes": self.episodes.tolist(),
                "own_episodes": self.own_episodes, "decisions": self.decisions.tolist(),
                "followed": self.followed.tolist(), "agreed": self.agreed.tolist(),
                "experts": experts,
                "steps_in_episode": self.steps_in_episode.tolist(),
                "mean_length": self.mean_length.tolist(), "judged": self.judged.tolist(),
                "weight": self.weight.tolist(), "progress": self.progress}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        if d["config"]["models"] != list(self.config.experts):
            raise ValueError(f"checkpoint's experts {d['config']['models']} differ from this "
                             f"selector's {list(self.config.experts)}")
        self.rng.bit_generator.state = d["rng"]
        self.current = np.asarray(d["current"], dtype=np.int64)
        self.episodes = np.asarray(d["episodes"], dtype=np.int64)
        self.own_episodes = int(d["own_episodes"])
        self.decisions = np.asarray(d["decisions"], dtype=np.int64)
        self.followed = np.asarray(d["followed"], dtype=np.int64)
        # checkpoints from before the agreement count lack it
        self.agreed = np.asarray(d.get("agreed", np.zeros(len(self.experts))), dtype=np.int64)
        if "mean_length" in d:  # checkpoints from before the credit rule lack it
            self.steps_in_episode = np.asarray(d["steps_in_episode"], dtype=np.int64)
            self.mean_length = np.asarray(d["mean_length"], dtype=np.float64)
            self.judged = np.asarray(d["judged"], dtype=np.int64)
            self.weight = np.asarray(d.get("weight", np.ones(len(self.current))),
                                     dtype=np.float64)
        else:
            self.steps_in_episode = np.zeros(len(self.current), dtype=np.int64)
            self.weight = np.ones(len(self.current))
        self.set_progress(float(d.get("progress", 0.0)))
        for i, s in d.get("experts", {}).items():
            self.experts[int(i)].load_state_dict(s)

    def card(self) -> dict[str, Any]:
        """What the trained model's card lists under ``training.experts`` (Alg. 5.1 inputs and
        how much each expert was used)."""
        w = np.asarray(self.config.weights)
        factors = self.credit_factors() if self.credit else np.ones(len(self.experts))
        learning = self.learning_weights() if self.credit else np.ones(len(self.experts))
        out = {
            "method": "DC (Alg. 4.1)" if len(self.experts) == 1 else "MEDC (Alg. 5.1)",
            "rate": self.rate, "threshold": self.threshold,
            **({"rate_start": self.config.resolved_rate, "rate_end": self.config.rate_end}
               if self.config.rate_end is not None else {}),
            "own_episodes": self.own_episodes,
            "experts": [
                {"ref": e.name, **({"digest": e.digest} if hasattr(e, "digest") else {}),
                 "qos": float(w[i]), "selection_probability": float(w[i] / w.sum()),
                 "episodes": int(self.episodes[i]), "decisions": int(self.decisions[i]),
                 "followed": int(self.followed[i]), "agreed": int(self.agreed[i])}
                | ({"mean_length": float(self.mean_length[i]), "credit": float(factors[i]),
                    "learning_weight": float(learning[i])}
                   if self.credit else {})
                for i, e in enumerate(self.experts)
            ],
        }
        if self.credit:
            out["credit"] = {"own_mean_length": float(self.mean_length[-1]),
                             "rate_in_force": self._credited()[0]}
        return out


def _marginals(p_joint: torch.Tensor, n: int, a: int) -> torch.Tensor:
    """(k, 1, A**N) joint probabilities -> (k, N, A) per-agent marginals (agent 0 = most
    significant digit, ``observations.encode_joint``)."""
    grid = p_joint.reshape(p_joint.shape[0], *([a] * n))
    dims = range(1, n + 1)
    return torch.stack([grid.sum(dim=tuple(d for d in dims if d != i)) if n > 1 else grid
                        for i in dims], dim=1)


def _decode(joint: torch.Tensor, n: int, a: int) -> torch.Tensor:
    weights = a ** torch.arange(n - 1, -1, -1)
    return (joint.unsqueeze(-1) // weights) % a


def _encode(actions: torch.Tensor, a: int) -> torch.Tensor:
    n = actions.shape[-1]
    return (actions * a ** torch.arange(n - 1, -1, -1)).sum(-1)


def resume_selector(meta: dict[str, Any]) -> DemonstrationSelector | None:
    """The selector of a checkpointed run (``checkpoint.load_checkpoint`` meta), rebuilt from
    the config it saved (None if the run had no experts); ``Trainer.resume`` then restores
    its state."""
    state = meta.get("selector")
    if not state or "config" not in state:
        return None
    from workers.mdrl.spec import EnvSpec

    c = state["config"]
    config = DemonstrationConfig(tuple(c["models"]), tuple(c["qos"]), c["rate"], c["threshold"],
                                 bool(c.get("credit", False)), c.get("rate_end"))
    return DemonstrationSelector.from_config(config, EnvSpec.from_dict(meta["env"]),
                                             seed=int(meta["run"]["seed"]))
