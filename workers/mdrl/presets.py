"""Named training set-ups (EnvSpec + ObservationSpec + PPOConfig) and config files.

Presets cover the Ch. 3 experiments (10 x 10, 1 km x 1 km, I = 1e9, 4 moves + idle):
`odmtl-Na-10x10` and `dmtl-Na-10x10` for N = 1, 2, 3, 4, 10, `cmtl-Na-10x10` for N = 1..3.
PPOConfig's defaults stay Table 3.2; presets use faster-learning settings measured on a 2-core
CPU (see `FAST_PPO`) and the product observations (`PRODUCT_OBSERVATION`); `table32` variants
(`...-t32`) keep the thesis observations and Table 3.2 exactly.

Ch. 4 presets (users A1W0 ... A4W3 of 4.7.1): `ch4-a{N}w{K}-sr` (shaped BFS reward, Eq. 8) and
`ch4-a{N}w{K}-sparse` (Eq. 9, S = 50) for N = 1..4 agents and exactly K = 0..3 walls, on a
30 x 30 grid over 1.5 km x 1.5 km (50 m moves), 8 directions + idle (Eq. 7), I = 1e9, ODMTL
w = 7 with wall maps, fast PPO (`FAST_PPO`); `...-t41` variants run Table 4.1 exactly.
`ch4-a{N}w{K}-{sr,sparse}-10x10` are the same users scaled down to 10 x 10 cells of 50 m with
the product observation (`CH4_SMALL_OBSERVATION`: belief map, w = 5), what trains on a CPU.

A config file (JSON or TOML) has the same fields, optionally on top of a preset:

    preset = "odmtl-3a-10x10"      # optional base
    [env]                          # EnvSpec fields (spec.py)
    agents = 3
    [observation]                  # ObservationSpec fields
    window = 3
    [ppo]                          # PPOConfig fields
    learning_rate = 1e-3
    [run]                          # RunConfig fields (train.py), optional
    eval_every = 5
    [experts]                      # DC / MEDC (medc.DemonstrationConfig), optional
    models = ["oracle", "runs/a1w0/model"]
    qos = [0.6, 0.9]               # R_S weights; default equal
    rate = 0.1                     # R_E; default 0.2 for one expert, 0.1 for several
    threshold = 0.05               # l
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from workers.mdrl.medc import DemonstrationConfig
from workers.mdrl.observations import ObservationSpec
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.spec import EnvSpec


@dataclass(frozen=True)
class Preset:
    """A training set-up: what env, which observation model, which PPO settings."""

    name: str
    env: EnvSpec
    observation: ObservationSpec
    ppo: PPOConfig
    description: str = ""
    run: dict[str, Any] = field(default_factory=dict)
    """RunConfig overrides that belong to the set-up (e.g. evaluation cadence)."""
    experts: DemonstrationConfig | None = None
    """Expert guidance (DC / MEDC, medc.py), from a config file's [experts] section."""

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "description": self.description, "env": self.env.to_dict(),
                "observation": self.observation.to_dict(), "ppo": self.ppo.to_dict(),
                "run": dict(self.run),
                **({"experts": self.experts.to_dict()} if self.experts else {})}


FAST_PPO = dict(learning_rate=1e-3, horizon=8192, num_envs=128, update_epochs=6,
                num_minibatches=4, anneal_lr=False, reward_scale=0.1)
"""Faster-learning PPO settings for presets, measured on ODMTL 3 agents 10x10 (2-core CPU):
50 epochs per update (Table 3.2) costs ~12x more compute per env step than 4-6 epochs for
little gain per sample; lr 1e-3 beat 5e-4; linear lr annealing did not help; 128 envs x 64
steps runs at 6-9k env steps/s on one thread of a shared 2-core CPU (3.8M steps in 10 min);
reward_scale 0.1 keeps the value targets O(1) so the critic does not lag."""


PRODUCT_OBSERVATION = dict(readings="mean", scale="fixed", belief=True)
"""What the product presets show the networks beyond the thesis maps (docs/learning.md): the
per-cell mean of the readings on a fixed log scale, and the team's posterior map of the target
(the Bayesian searcher's filter). ODMTL also widens its windows to 5 x 5."""


def _make(kind: str, agents: int, fast: bool = True) -> Preset:
    env = EnvSpec(rows=10, cols=10, agents=agents)
    if fast:
        obs = ObservationSpec(kind=kind, window=5 if kind == "odmtl" else 3,
                              **PRODUCT_OBSERVATION)
    else:
        obs = ObservationSpec(kind=kind, window=3)
    ppo = PPOConfig(**FAST_PPO) if fast else PPOConfig()
    name = f"{kind}-{agents}a-10x10" + ("" if fast else "-t32")
    desc = (f"{kind.upper()}, {agents} agent(s), 10x10 grid over 1 km x 1 km, I = 1e9, "
            f"4 moves + idle, shaped team reward (Eq. 5); "
            + ("belief map, mean readings on a fixed scale, fast PPO settings" if fast
               else "thesis observations, PPO exactly as Table 3.2"))
    return Preset(name, env, obs, ppo, desc)


CH4_OBSERVATION = dict(kind="odmtl", window=7, walls=True, readings="mean", scale="fixed")
"""Ch. 4 observation (4.3): ODMTL w = 7 with the windowed and downsized walls maps standing in
for the CAE walls embedding; walls maps on even with 0 walls, so all 16 users share one input
layout per team size (any of them can be another's DC expert). Mean readings on a fixed scale
as the product presets. No belief map, as the thesis; the ``-belief`` variants add it."""

CH4_BELIEF_OBSERVATION = dict(CH4_OBSERVATION, belief=True)
"""The Ch. 4 observation plus the team's posterior map of the source (belief.py, which models
the walls): the product observation at the thesis size. The filter keeps running sums, one
compiled column per new reading (~10 ms per step of 128 envs at 30 x 30 with 3 agents), where
it used to keep two 900 x 900 matrices per env rebuilt at every reset (~60 ms each)."""

CH4_ROUTE_OBSERVATION = dict(CH4_BELIEF_OBSERVATION, route=True)
"""The belief observation plus the walking-distance maps (observations.py, ``route``): each
window cell's expected BFS steps to the posterior's most probable cells, relative to the
agent's own. Added because the belief policy at 30 x 30 failed where the source was known but
a wall stood in the way (docs/learning.md)."""

TABLE_41_PPO = dict(update_epochs=20)
"""Table 4.1: Table 3.2 (PPOConfig's defaults: lr 3e-4, clip 0.2, c2 0.01, gamma 0.99,
lambda 0.95, H = 4000) with 20 epochs per update instead of 50."""


def _make_ch4(agents: int, walls: int, reward: str, table41: bool = False,
              belief: bool = False, route: bool = False) -> Preset:
    env = EnvSpec(rows=30, cols=30, area_m=(1500.0, 1500.0), agents=agents, moves=8,
                  walls=(walls, walls), reward=reward, sparse_bonus=50.0)
    ppo = PPOConfig(**(TABLE_41_PPO if table41 else FAST_PPO))
    tag = "sr" if reward == "shaped" else "sparse"
    name = f"ch4-a{agents}w{walls}-{tag}" + ("-t41" if table41 else "") + (
        "-route" if route else "-belief" if belief else "")
    what = ("shaped BFS team reward (Eq. 8, MDRL-SR)" if reward == "shaped"
            else "sparse team reward (Eq. 9, S = 50, MDRL-Sparse / the base of MDRL-DC)")
    desc = (f"Ch. 4 user A{agents}W{walls}: {agents} agent(s), exactly {walls} wall(s) from the "
            f"sides, 30x30 grid over 1.5 km x 1.5 km (50 m moves), I = 1e9, 8 directions + idle "
            f"(Eq. 7), {what}; ODMTL w = 7 with wall maps (for the CAE embedding), mean readings "
            f"on a fixed scale, "
            + ("the team's belief map and the walking-distance maps to it; " if route
               else "and the team's belief map (the product observation); " if belief
               else "no belief map (as the thesis; see the -belief variant); ")
            + ("PPO exactly as Table 4.1" if table41
               else "fast PPO settings (FAST_PPO), not Table 4.1's 20 epochs (see the -t41 "
                    "variant)"))
    obs = (CH4_ROUTE_OBSERVATION if route else CH4_BELIEF_OBSERVATION if belief
           else CH4_OBSERVATION)
    return Preset(name, env, ObservationSpec(**obs), ppo, desc)


CH4_SMALL_OBSERVATION = dict(kind="odmtl", window=5, walls=True, readings="mean", scale="fixed",
                             belief=True)
"""The product observation of the scaled-down Ch. 4 setting (10 x 10 cells of 50 m): the Ch. 4
maps with the team's posterior map of the target (``belief``, which models the walls; at 100
cells its per-env matrices are 80 KB and rebuilt in well under a millisecond, unlike at 900)
and ODMTL's 5 x 5 windows of the product presets (7 x 7 windows cover most of a 10 x 10 map)."""


def _make_ch4_small(agents: int, walls: int, reward: str) -> Preset:
    env = EnvSpec(rows=10, cols=10, area_m=(500.0, 500.0), agents=agents, moves=8,
                  walls=(walls, walls), reward=reward, sparse_bonus=50.0)
    tag = "sr" if reward == "shaped" else "sparse"
    desc = (f"Ch. 4 user A{agents}W{walls} scaled down to 10x10 cells of 50 m (500 m x 500 m): "
            f"{agents} agent(s), exactly {walls} wall(s) from the sides, 8 directions + idle, "
            f"I = 1e9, {'shaped BFS' if tag == 'sr' else 'sparse (Eq. 9)'} team reward; ODMTL "
            f"w = 5 with wall maps and the belief map, mean readings on a fixed scale, fast PPO")
    return Preset(f"ch4-a{agents}w{walls}-{tag}-10x10", env,
                  ObservationSpec(**CH4_SMALL_OBSERVATION), PPOConfig(**FAST_PPO), desc)


PRESETS: dict[str, Preset] = {}
for _kind, _agents in ([("odmtl", n) for n in (1, 2, 3, 4, 10)]
                       + [("dmtl", n) for n in (1, 2, 3, 4, 10)]
                       + [("cmtl", n) for n in range(1, 4)]):
    for _fast in (True, False):
        _p = _make(_kind, _agents, _fast)
        PRESETS[_p.name] = _p
for _agents in range(1, 5):
    for _walls in range(4):
        for _reward in ("shaped", "sparse"):
            for _t41, _belief, _route in ((False, False, False), (True, False, False),
                                          (False, True, False), (False, True, True)):
                _p = _make_ch4(_agents, _walls, _reward, _t41, _belief, _route)
                PRESETS[_p.name] = _p
        for _reward in ("shaped", "sparse"):
            _p = _make_ch4_small(_agents, _walls, _reward)
            PRESETS[_p.name] = _p


def preset_families() -> str:
    """The preset names with their numbers written N (e.g. ``odmtl-Na-NxN``): the list in
    short, for an error that cannot name a close one; derived, so never out of date."""
    return ", ".join(sorted({re.sub(r"\d+", "N", name) for name in PRESETS}))


LIST_PRESETS = "`drlaas train --list-presets`"
"""How a user lists every preset with its description."""


def get_preset(name: str) -> Preset:
    """The preset called `name`; an unknown one is one line naming it with the closest names
    (the whole list of ~190 names buried the typo)."""
    try:
        return PRESETS[name]
    except KeyError:
        close = difflib.get_close_matches(str(name), PRESETS, n=3)
        names = " or ".join([", ".join(close[:-1]), close[-1]] if len(close) > 1 else close)
        hint = f"did you mean {names}?" if close else f"the families are {preset_families()}"
        raise ValueError(f"unknown preset {name!r}; {hint} ({LIST_PRESETS} lists them all)"
                         ) from None


def _merge(base: dict[str, Any], changes: dict[str, Any], what: str) -> dict[str, Any]:
    if not isinstance(changes, dict):
        raise ValueError(f"config section [{what}] must be a table/object, got {changes!r}")
    return {**base, **changes}


def preset_from_dict(doc: dict[str, Any], name: str = "custom") -> Preset:
    """Build a preset from a config document (sections env/observation/ppo/run, optional base)."""
    if not isinstance(doc, dict):  # a file holding `[]` or `3` is JSON, not a config
        raise ValueError(f"config must be a JSON/TOML object (a table of sections), got "
                         f"{type(doc).__name__}")
    allowed = {"preset", "name", "description", "env", "observation", "ppo", "run",
               "experts"}
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise ValueError(f"config: unknown top-level key(s) {unknown}; allowed: {sorted(allowed)}")
    for key in ("preset", "name", "description"):  # a list preset read "unhashable type: 'list'"
        if not isinstance(doc.get(key, ""), str) and not (key == "preset" and doc[key] is None):
            raise ValueError(f"config: {key} must be a string, got {doc[key]!r}")
    base = get_preset(doc["preset"]) if doc.get("preset") else None
    env = _merge(base.env.to_dict() if base else {}, doc.get("env", {}), "env")
    obs = _merge(base.observation.to_dict() if base else {}, doc.get("observation", {}),
                 "observation")
    ppo = _merge(base.ppo.to_dict() if base else {}, doc.get("ppo", {}), "ppo")
    run = _merge(dict(base.run) if base else {}, doc.get("run", {}), "run")
    from workers.mdrl.train import RunConfig

    RunConfig.from_dict(run)  # checked now (names the field), not after training
    experts = DemonstrationConfig.from_dict(doc["experts"]) if "experts" in doc else None
    return Preset(name=doc.get("name", name), env=EnvSpec.from_dict(env),
                  observation=ObservationSpec.from_dict(obs), ppo=PPOConfig.from_dict(ppo),
                  description=doc.get("description", base.description if base else ""),
                  run=run, experts=experts)


def _no_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object whose keys are all distinct: json keeps the last of a repeated key
    without a word, so ``{"preset": "odmtl-2a-10x10", ..., "preset": "cmtl-2a-10x10"}``
    trained the second preset."""
    doc: dict[str, Any] = {}
    for key, value in pairs:
        if key in doc:
            raise ValueError(f"key {key!r} given twice in one object")
        doc[key] = value
    return doc


def load_config(path: str | Path) -> Preset:
    """Read a JSON (.json) or TOML (.toml) config file into a Preset."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    if path.suffix not in (".json", ".toml"):
        raise ValueError(f"config {path}: expected a .json or .toml file")
    kind = path.suffix[1:].upper()
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not valid {kind} (not UTF-8 text)") from None
    try:  # the parser's own message names neither the file nor the format
        doc = (json.loads(text, object_pairs_hook=_no_duplicate_keys) if kind == "JSON"
               else tomllib.loads(text))  # TOML refuses a repeated key itself
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: "
                         f"{exc.msg})") from None
    except tomllib.TOMLDecodeError as exc:  # its message ends with "(at line L, column C)"
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    except RecursionError:
        raise ValueError(f"config {path}: {kind} nested too deeply") from None
    except ValueError as exc:  # a repeated key (_no_duplicate_keys)
        raise ValueError(f"{path}: not a usable {kind} config ({exc})") from None
    return preset_from_dict(doc, name=path.stem)


def with_ppo(preset: Preset, **changes: Any) -> Preset:
    """A copy of `preset` with some PPOConfig fields changed."""
    return dataclasses.replace(preset, ppo=dataclasses.replace(preset.ppo, **changes))
