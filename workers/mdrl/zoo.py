"""The model zoo: one trained model per thesis row, shipped in ``models/`` (issue 9).

Each entry names a preset, a seed and a budget; ``train_entry`` trains it (resumable: a
killed run continues from its checkpoint in ``runs/zoo/NAME``), evaluates the greedy policy
on held-out episodes under both reading models, and writes ``models/NAME`` (safetensors +
card, a few KB). The card's ``zoo`` section records what a buyer wants to know: preset, seed,
env steps, wall-clock, and the held-out success / time / cost with 95% CIs next to the oracle.

``drlaas zoo train [NAME ...]`` (``make zoo``) retrains them; ``drlaas eval --policy
models/NAME`` evaluates one; ``benchmarks/policy_table.py`` compares them with the thesis.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from workers.mdrl.baselines import OraclePolicy, make_baseline
from workers.mdrl.curve import CURVE_KEY, training_curve
from workers.mdrl.evaluate import EvalReport, evaluate
from workers.mdrl.experts import BUILTINS
from workers.mdrl.modelio import CARD, card_observation, load_model
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.presets import get_preset
from workers.mdrl.spec import EnvSpec

HELDOUT_SEED = 20_261_124
"""Seed of the held-out episodes in the cards (training evaluates on RunConfig.eval_seed)."""
HELDOUT_EPISODES = 1000
READING_MODELS = ("poisson", "expected")


@dataclass(frozen=True)
class ZooEntry:
    """One shipped model: which preset, which seed, how long."""

    preset: str
    """A preset name, or 'generalist' (generalist.py: one ODMTL actor over many set-ups)."""
    minutes: float
    seed: int = 0
    steps: int | None = None
    experts: tuple[str, ...] = ()
    """Zoo models (names in the same models directory) or built-in experts (``oracle``,
    ``bayes``, ...) guiding the run as MEDC experts."""
    expert_rate: float | None = None
    """R_E of those experts; None = the DemonstrationConfig default (Table 4.1 / 5.3)."""
    init_from: str | None = None
    """A zoo model (name in the same models directory) whose weights the run starts from: a
    fine-tuning stage on top of an earlier entry."""
    ppo: tuple[tuple[str, Any], ...] = ()
    """PPOConfig fields that differ from the preset's, e.g. a lower learning rate to fine-tune."""


_ODMTL_MINUTES = {2: 30, 3: 30, 4: 30, 10: 25}
_CH4_EXPERTS_30 = tuple(f"ch4-{u}-30x30" for u in ("a1w0", "a1w3", "a2w2"))

ZOO: dict[str, ZooEntry] = {
    # 25-30 minutes (the bound per model) where a 6-minute run missed Table 3.5
    **{f"odmtl-{n}a": ZooEntry(f"odmtl-{n}a-10x10", minutes=_ODMTL_MINUTES.get(n, 6))
       for n in (1, 2, 3, 4, 10)},
    **{f"dmtl-{n}a": ZooEntry(f"dmtl-{n}a-10x10", minutes=6) for n in (1, 2, 3, 4, 10)},
    **{f"cmtl-{n}a": ZooEntry(f"cmtl-{n}a-10x10", minutes=6) for n in (1, 2, 3)},
    "odmtl-generalist": ZooEntry("generalist", minutes=20),
    # Ch. 4 (issue 10), on the 10 x 10 scale-down of the walls setting with the belief map: the
    # experts of the MEDC benchmark (the thesis' A1W0, A1W3, A2W2) and the final A3W3 policy
    **{f"ch4-{u}-10x10": ZooEntry(f"ch4-{u}-sr-10x10", minutes=5)
       for u in ("a1w0", "a1w3", "a2w2")},
    "ch4-a3w3-10x10": ZooEntry("ch4-a3w3-sr-10x10", minutes=60),
    # the same experts at the thesis size (30 x 30, no belief map), 20 minutes each
    **{f"ch4-{u}-30x30": ZooEntry(f"ch4-{u}-sr", minutes=20) for u in ("a1w0", "a1w3", "a2w2")},
    # the final A3W3 policy at the thesis size: the shaped reward with the three experts above
    # guiding it (MEDC, Alg. 5.1 defaults), on the thesis observation and on the product one
    # (with the team's belief map)
    "ch4-a3w3-30x30": ZooEntry("ch4-a3w3-sr", minutes=61, experts=_CH4_EXPERTS_30),
    "ch4-a3w3-belief-30x30": ZooEntry("ch4-a3w3-sr-belief", minutes=75,
                                      experts=_CH4_EXPERTS_30),
    # the same recipe with the walking-distance maps to the belief (``-route``): the one that
    # reaches issue 10's final target at this size (docs/learning.md)
    "ch4-a3w3-route-30x30": ZooEntry("ch4-a3w3-sr-route", minutes=110, experts=_CH4_EXPERTS_30),
    # the benchmark's experts on the route presets (benchmarks/medc, --route): 1M steps each
    **{f"ch4-{u}-route-30x30": ZooEntry(f"ch4-{u}-sr-route", minutes=20, steps=1_000_000)
       for u in ("a1w0", "a1w3", "a2w2")},
    # the other users of the thesis' FRL comparison (Fig. 5.7: the first six of A1W0, A3W0,
    # A2W1, A2W2, A2W3, A3W1 share their models with A3W2 and A3W3), trained the same way
    **{f"ch4-{u}-route-30x30": ZooEntry(f"ch4-{u}-sr-route", minutes=20, steps=1_000_000)
       for u in ("a3w0", "a2w1", "a2w3", "a3w1")},
}


BASELINE_POLICIES = ("bayes", "uniform", "random")
"""Baselines (baselines.py) whose figures a card lists next to the model's, on its episodes."""


def heldout(policy: Any, spec: Any, episodes: int = HELDOUT_EPISODES,
            seed: int = HELDOUT_SEED) -> dict[str, Any]:
    """Greedy held-out figures of ``policy`` under each reading model, with the oracle's time
    and the baselines' figures on the same episodes."""
    out: dict[str, Any] = {"episodes": episodes, "seed": seed}
    for readings in READING_MODELS:
        s = spec.replace(readings=readings)
        report = evaluate(policy, s, episodes, seed=seed)
        oracle = evaluate(OraclePolicy(), s, episodes, seed=seed)
        out[readings] = summary(report) | {"oracle_time": oracle.time_mean,
                                           "baselines": baselines(s, episodes, seed)}
    return out


def baselines(spec: Any, episodes: int, seed: int) -> dict[str, Any]:
    """{name: figures} of each of BASELINE_POLICIES on ``episodes`` seeded episodes of ``spec``
    (the random policy's own seed is 0: the same figures every time)."""
    return {name: summary(evaluate(make_baseline(name), spec, episodes, seed=seed))
            for name in BASELINE_POLICIES}


def add_baselines(model_dir: Path) -> dict[str, Any]:
    """Write the baselines' figures into the ``zoo.heldout`` of a card made before cards had
    them, on the card's own held-out episodes (its env, episode count and seed); the model's
    figures are left as they are. Returns the held-out section."""
    card_path = Path(model_dir) / CARD
    card = json.loads(card_path.read_text())
    held = card["zoo"]["heldout"]
    spec = EnvSpec.from_dict(card["env"])
    for readings in READING_MODELS:
        if readings in held:
            held[readings]["baselines"] = baselines(spec.replace(readings=readings),
                                                    held["episodes"], held["seed"])
    card_path.write_text(json.dumps(card, indent=1))
    return held


def attach_run_curve(model_dir: Path, run_dir: Path) -> dict[str, Any]:
    """Write the training curve of ``run_dir/metrics.csv`` into the card of ``model_dir`` (a
    model trained before cards had curves); ValueError unless the run ends at the card's env
    steps (another run's curve would be a false claim). Returns the curve section."""
    card_path = Path(model_dir) / CARD
    card = json.loads(card_path.read_text())
    curve = training_curve(Path(run_dir) / "metrics.csv")
    last = curve["points"][-1]["step"] if curve["points"] else None
    if last != card.get("training", {}).get("env_steps"):
        raise ValueError(f"{run_dir} ends at {last} env steps, the card of {model_dir} says "
                         f"{card.get('training', {}).get('env_steps')}: not this model's run")
    card[CURVE_KEY] = curve
    card_path.write_text(json.dumps(card, indent=1))
    return curve


def summary(report: EvalReport) -> dict[str, Any]:
    """The card's figures of one evaluation."""
    s = report.summary
    return {"success": s["success_rate"], "time": s["time_mean"], "time_ci": s["time_ci"],
            "cost": s["cost_mean"], "cost_ci": s["cost_ci"]}


def train_entry(name: str, models: Path, runs: Path, minutes: float | None = None,
                progress: bool = False) -> Path:
    """Train (or resume) zoo entry ``name``; writes ``models/NAME``; returns that directory."""
    if name not in ZOO:
        raise ValueError(f"unknown zoo model {name!r}; known: {', '.join(ZOO)}")
    entry = ZOO[name]
    budget = {"minutes": minutes if minutes is not None else entry.minutes,
              "total_steps": entry.steps}
    run_dir = runs / name
    if entry.preset == "generalist":
        trainer = _generalist(entry, run_dir, budget)
    else:
        experts = tuple(e if e in BUILTINS else str(models / e) for e in entry.experts)
        init = str(models / entry.init_from) if entry.init_from else None
        trainer = _trainer(entry, run_dir, budget, progress, experts, init)
    trainer.train()
    return publish_run(name, run_dir, models)


def publish_run(name: str, run_dir: Path, models: Path) -> Path:
    """Write ``models/NAME`` from a finished run of zoo entry ``name``: its model with the zoo
    card section (held-out figures, ``heldout``) and the run's curve. A run made outside
    ``train_entry`` (``drlaas train`` with the entry's preset, seed and experts) is checked
    against the entry first: ValueError naming what differs. Returns the model directory."""
    entry = ZOO[name]
    run_dir = Path(run_dir)
    card_file = run_dir / "model" / CARD
    try:
        card = json.loads(card_file.read_text())
        if not isinstance(card, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as exc:
        raise ValueError(f"{card_file}: not a readable model card ({exc})") from None
    spec = None
    if entry.preset != "generalist":
        _check_run_is_entry(name, entry, card, models)
        spec = get_preset(entry.preset).env
    # built beside the published model and swapped in only when complete: a failure (a bad
    # weights file, an interrupted held-out evaluation) leaves the published model as it was
    target = models / name
    staging = models / f".{name}.publishing"
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(run_dir / "model", staging)
    try:
        policy = load_model(staging)
        training = card.get("training", {})
        card["zoo"] = {"name": name, "preset": entry.preset, "seed": entry.seed,
                       "env_steps": training.get("env_steps"),
                       "wall_clock_s": round(float(training.get("wall_time_s", 0.0)), 1),
                       "heldout": heldout(policy, spec if spec is not None else policy.env_spec)}
        card[CURVE_KEY] = training_curve(run_dir / "metrics.csv")
        (staging / CARD).write_text(json.dumps(card, indent=1))
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    old = models / f".{name}.replaced"
    shutil.rmtree(old, ignore_errors=True)
    if target.exists():
        target.rename(old)
    staging.rename(target)
    shutil.rmtree(old, ignore_errors=True)
    return target


def _check_run_is_entry(name: str, entry: ZooEntry, card: dict[str, Any], models: Path) -> None:
    """The run's card says it trained the entry's set-up: env, observation, seed, experts."""
    preset = get_preset(entry.preset)
    run = card.get("training", {}).get("run", {})
    want_experts = [e if e in BUILTINS else str(models / e) for e in entry.experts]
    have_experts = [e["ref"] for e in card.get("training", {}).get("experts", {}).get(
        "experts", [])]
    checks = {"env": (card["env"], preset.env.to_dict()),
              "observation": (card_observation(card), preset.observation.to_dict()),
              "seed": (run.get("seed"), entry.seed),
              "experts": ([str(Path(e)) for e in have_experts],
                          [str(Path(e)) for e in want_experts])}
    wrong = [k for k, (have, want) in checks.items() if have != want]
    if wrong:
        have, want = [checks[k][0] for k in wrong], [checks[k][1] for k in wrong]
        raise ValueError(f"the run is not zoo entry {name!r}: its {wrong} differ ({have} "
                         f"against {want})")


def _generalist(entry: ZooEntry, run_dir: Path, budget: dict[str, Any]) -> Any:
    from workers.mdrl.generalist import GeneralistTrainer
    from workers.mdrl.presets import FAST_PPO
    from workers.mdrl.train import RunConfig

    if (run_dir / "checkpoint" / "generalist.json").is_file():
        return GeneralistTrainer.resume(run_dir, run_overrides=budget)
    run = RunConfig(seed=entry.seed, tensorboard=False, progress=False, **budget)
    ppo = PPOConfig(**{**FAST_PPO, "num_envs": 64, "horizon": 4096})
    return GeneralistTrainer(ppo, run, run_dir)


def _trainer(entry: ZooEntry, run_dir: Path, budget: dict[str, Any], progress: bool,
             experts: tuple[str, ...] = (), init_from: str | None = None) -> Any:
    from workers.mdrl.medc import DemonstrationConfig, DemonstrationSelector, resume_selector
    from workers.mdrl.train import RunConfig, Trainer

    preset = get_preset(entry.preset)
    if (run_dir / "checkpoint").is_dir():
        meta = json.loads((run_dir / "checkpoint" / "state.json").read_text())
        trainer = Trainer.resume(run_dir, run_overrides={**budget, "progress": progress},
                                 selector=resume_selector(meta))
    else:
        run = RunConfig.from_dict({**preset.run, **budget, "seed": entry.seed,
                                   "progress": progress, "tensorboard": False,
                                   "init_from": init_from})
        selector = None
        if experts:
            selector = DemonstrationSelector.from_config(
                DemonstrationConfig(experts, (), entry.expert_rate), preset.env, seed=entry.seed)
        ppo = dataclasses.replace(preset.ppo, **dict(entry.ppo))
        trainer = Trainer(preset.env, preset.observation, ppo, run, out=run_dir,
                          selector=selector)
    return trainer
