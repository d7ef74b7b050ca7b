"""The one task-spec type: round trip, bounds named by dotted field, JSON Schema = parser."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import jsonschema_rs  # schemathesis' validator (a dev dependency)
import numpy as np
import pytest

from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.trainingspec import (
    INTENSITY_BOUNDS,
    MAX_SPEC_BYTES,
    SpecError,
    TrainingSpec,
    trainingspec_json_schema,
)

GOOD = {
    "env": {"rows": 6, "cols": 6, "agents": 2},
    "budget": {"steps": 2000},
    "seed": 1,
    "experts": ["bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"],
}


def test_round_trip_and_defaults() -> None:
    spec = TrainingSpec.from_dict(GOOD)
    assert spec.steps == 2000 and spec.env.agents == 2 and spec.ppo.batch_steps <= 500
    doc = spec.to_dict()
    assert TrainingSpec.from_dict(doc) == spec
    assert TrainingSpec.from_json(json.dumps(doc)) == spec
    preset = TrainingSpec.from_dict(
        {**GOOD, "algorithm": {"preset": "odmtl-3a-10x10", "ppo": {"update_epochs": 3}}}
    )
    assert preset.ppo.num_envs == 128 and preset.ppo.update_epochs == 3
    assert TrainingSpec.from_dict(preset.to_dict()) == preset


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"budget": {}}, "budget"),
        ({"budget": {"steps": 0}}, "budget.steps"),
        ({"budget": {"steps": 1.5}}, "budget.steps"),
        ({"budget": {"minutes": float("inf")}}, "budget.minutes"),
        ({"env": {"rows": 1}}, "env.rows"),
        ({"env": {"agents": 16, "rows": 3, "cols": 5}}, "env.agents"),
        ({"env": {"intensity": 1e308}}, "env.intensity"),
        ({"env": {"intensity": float("nan")}}, "env.intensity"),
        (
            {"env": {"intensity": {"kind": "choice", "values": [1e9, -1]}}},
            "env.intensity.values[1]",
        ),
        ({"env": {"walls": [0, 9]}}, "env.walls"),
        ({"env": {"walls": [1, 1], "rows": 3}}, "env.walls"),
        ({"env": {"moves": True}}, "env.moves"),
        ({"env": {"colour": "red"}}, "env.colour"),
        ({"observation": {"kind": "xyz"}}, "observation.kind"),
        ({"observation": {"window": 7}}, "observation.window"),
        ({"observation": {"window": 4}}, "observation.window"),
        ({"seed": -1}, "seed"),
        ({"algorithm": {"ppo": {"horizon": 0}}}, "algorithm.ppo.horizon"),
        ({"algorithm": {"preset": "nope"}}, "algorithm.preset"),
        ({"ppo": {"horizon": 64}}, "ppo"),
        ({"experts": ["/etc/passwd"]}, "experts[0]"),
        ({"experts": ["a/../b"]}, "experts[0]"),
        ({"experts": ["m1", "m1"]}, "experts"),
        # a trailing newline passed `$` (re.match), so one model could guide as two experts
        ({"experts": ["m1", "m1\n"]}, "experts[1]"),
        ({"format": "other/2"}, "format"),
        ({"observation": {"walls_embedding": "/etc/cae"}}, "observation.walls_embedding"),
        ({"observation": {"walls_embedding_size": 0}}, "observation.walls_embedding_size"),
        # without its CAE the size was accepted and ignored: the UI refused it, the API not
        ({"observation": {"walls_embedding_size": 64}}, "observation.walls_embedding_size"),
        ({"env": {"sparse_bonus": -50}}, "env.sparse_bonus"),
        ({"observation": {"route": True}}, "observation.route"),
        ({"observation": {"route": True, "belief": True, "kind": "dmtl"}}, "observation.route"),
        ({"selection": {"keep_best": "fastest"}}, "selection.keep_best"),
        ({"selection": {"keep_best": "time", "eval_every": 0}}, "selection.eval_every"),
        ({"selection": {"eval_every": 3}}, "selection.eval_every"),
        ({"selection": ["time"]}, "selection"),
        # a schedule over a budget of steps only (it was accepted and ignored on the platform)
        ({"algorithm": {"ppo": {"anneal_lr": True}}, "budget": {"minutes": 1}},
         "algorithm.ppo.anneal_lr"),
        # walls that leave 15 agents no room: refused here (the gateway's 422), not by every
        # worker's env after the task was paid for
        ({"env": {"rows": 4, "cols": 4, "agents": 15, "moves": 8, "walls": [2, 3]}}, "env.walls"),
        ({"env": {"rows": 5, "cols": 5, "agents": 10, "walls": [5, 5]}}, "env.walls"),  # 19.5%
        ({"env": {"rows": 10, "cols": 10, "walls": [1, 2], "wall_length": [64, 64]}},
         "env.wall_length"),
        ({"outcome_key": "0x1234"}, "outcome_key"),
        ({"outcome_key": "0x" + "01" * 64}, "outcome_key"),  # hex of the length, off the curve
    ],
)
def test_errors_name_the_dotted_field(change: dict, field: str) -> None:
    doc = {**GOOD, **change}
    if "env" in change:
        doc["env"] = {**GOOD["env"], **change["env"]}
    with pytest.raises(SpecError) as info:
        TrainingSpec.from_dict(doc)
    assert info.value.field == field, info.value


def test_a_walls_cae_is_named_by_cid_and_round_trips() -> None:
    """observation.walls_embedding (Ch. 4 CAE) by model CID, with its d; off by default."""
    cid = "bafybeigdyrzt5sfp7udm7hu76uh7y26nf3efuylqabf3oclgtqy55fbzdi"
    doc = {**GOOD, "observation": {**GOOD.get("observation", {}), "walls_embedding": cid,
                                   "walls_embedding_size": 32}}
    spec = TrainingSpec.from_dict(doc)
    assert spec.observation.walls_embedding == cid and spec.observation.walls_embedding_size == 32
    assert TrainingSpec.from_dict(spec.to_dict()) == spec
    assert "walls_embedding" not in TrainingSpec.from_dict(GOOD).to_dict()["observation"]
    schema = trainingspec_json_schema()
    v = jsonschema_rs.Draft202012Validator(schema, validate_formats=True)
    assert v.is_valid(spec.to_dict())
    assert not v.is_valid({**doc, "observation": {"walls_embedding": "../x"}})


def test_integral_numbers_are_integers_as_in_json_schema() -> None:
    """JSON Schema's integer and enum compare numbers by value: 8.0 is 8 (a client or a
    language that writes every number as a double still sends a valid spec)."""
    doc = {**GOOD, "env": {**GOOD["env"], "moves": 8.0, "rows": 6.0}}
    spec = TrainingSpec.from_dict(doc)
    assert spec.env.moves == 8 and type(spec.env.moves) is int and spec.env.rows == 6
    with pytest.raises(SpecError):
        TrainingSpec.from_dict({**GOOD, "env": {**GOOD["env"], "moves": 8.5}})


def test_one_size_limit_and_bad_json() -> None:
    with pytest.raises(SpecError, match="limit"):
        TrainingSpec.from_json(b" " * (MAX_SPEC_BYTES + 1))
    with pytest.raises(SpecError, match="not JSON"):
        TrainingSpec.from_json(b"{nope")


def test_json_schema_carries_the_parser_bounds() -> None:
    schema = trainingspec_json_schema()
    v = jsonschema_rs.Draft202012Validator(schema, validate_formats=True)
    assert v.is_valid(TrainingSpec.from_dict(GOOD).to_dict())
    env = schema["properties"]["env"]["properties"]
    assert (env["rows"]["minimum"], env["rows"]["maximum"]) == (2, 64)
    assert env["agents"]["maximum"] == 16
    for bad in (
        {**GOOD, "env": {"rows": 65}},
        {**GOOD, "env": {"intensity": 1e13}},
        {**GOOD, "budget": {}},
        {**GOOD, "observation": {"window": 4}},
        {**GOOD, "extra": 1},
    ):
        assert not v.is_valid(bad)
        with pytest.raises(SpecError):
            TrainingSpec.from_dict(bad)


@pytest.mark.parametrize("intensity", INTENSITY_BOUNDS)
def test_the_intensity_bounds_keep_the_env_math_finite(intensity: float) -> None:
    # the extreme corner of the bounds: smallest cells, largest detector and dwell
    doc = {
        "env": {
            "rows": 64,
            "cols": 64,
            "agents": 2,
            "area_m": [10.0, 10.0],
            "intensity": intensity,
            "detector_area_cm2": 1e4,
            "dwell_min": 1e3,
        },
        "budget": {"steps": 1},
    }
    spec = TrainingSpec.from_dict(doc)
    env = TargetLocalizationEnv(spec.env, num_envs=4, seed=0)
    for _ in range(20):
        actions = np.array([[np.flatnonzero(m)[0] for m in env.action_mask()[b]] for b in range(4)])
        env.step(actions)
    assert np.isfinite(env.readings).all() and np.isfinite(env.mean_reading).all()


def test_the_core_type_imports_nothing_from_the_platform() -> None:
    root = Path(__file__).resolve().parents[2] / "workers" / "mdrl"
    for name in ("trainingspec.py", "specfields.py", "resources.py"):
        tree = ast.parse((root / name).read_text())
        mods = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        mods += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        assert not [m for m in mods if m.startswith(("backend", "workers.daemon"))], name


def test_outcome_key_round_trips_and_is_optional() -> None:
    # the public key of private key 1 is the curve's generator point G
    g = (
        "0x79be667ef9dcbbac55a06295ce870b07029bfcdb2dce28d959f2815b16f81798"
        "483ada7726a3c4655da4fbfc0e1108a8fd17b448a68554199c47d08ffb10d4b8"
    )
    spec = TrainingSpec.from_dict({**GOOD, "outcome_key": g.upper().replace("0X", "0x")})
    assert spec.outcome_key == g
    assert TrainingSpec.from_dict(spec.to_dict()) == spec
    assert "outcome_key" not in TrainingSpec.from_dict(GOOD).to_dict()  # old spec CIDs stay


def test_a_route_observation_round_trips_and_is_off_by_default() -> None:
    doc = {**GOOD, "observation": {"belief": True, "route": True}}
    spec = TrainingSpec.from_dict(doc)
    assert spec.observation.route and TrainingSpec.from_dict(spec.to_dict()) == spec
    assert "route" not in TrainingSpec.from_dict(GOOD).to_dict()["observation"]
    # the same rule in the published JSON Schema (clients see it before they send a spec)
    v = jsonschema_rs.Draft202012Validator(trainingspec_json_schema())
    assert v.is_valid(doc) and v.is_valid(spec.to_dict())
    assert not v.is_valid({**GOOD, "observation": {"route": True}})
    assert not v.is_valid({**GOOD, "observation": {"route": True, "belief": True,
                                                   "kind": "cmtl"}})


def test_selection_keeps_the_final_policy_unless_asked() -> None:
    """``selection.keep_best``: the worker delivers the best evaluated policy (RunConfig)."""
    plain = TrainingSpec.from_dict(GOOD)
    assert plain.selection.keep_best is None and "selection" not in plain.to_dict()
    doc = {**GOOD, "selection": {"keep_best": "time"}}
    spec = TrainingSpec.from_dict(doc)
    assert (spec.selection.keep_best, spec.selection.eval_every) == ("time", 5)
    assert TrainingSpec.from_dict(spec.to_dict()) == spec
    assert TrainingSpec.from_dict({**GOOD, "selection": {"keep_best": None}}) == plain
    v = jsonschema_rs.Draft202012Validator(trainingspec_json_schema())
    assert v.is_valid(doc) and v.is_valid(spec.to_dict())
    assert not v.is_valid({**GOOD, "selection": {"keep_best": "fastest"}})
    assert not v.is_valid({**GOOD, "selection": {"eval_every": 3}})


_ODD_VALUES = [{}, {"x": {}}, [], [[]], [{}], "x", "", None, True, 1e300, -1, float("nan")]


def _paths(doc: object, prefix: tuple = ()) -> list[tuple]:
    """Every key path (dict keys and list indices) of a JSON document, leaves and inner nodes."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*prefix, i))
    return out


def _replaced(doc: object, path: tuple, value: object) -> object:
    doc = json.loads(json.dumps(doc))
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return doc


def test_any_wrong_type_anywhere_is_a_spec_error_never_a_crash() -> None:
    """Each field of a full spec replaced by objects, arrays, strings, null, ... is either
    accepted or a SpecError naming a field: never a TypeError from a lookup (a dict preset
    name once crashed the gateway with 'unhashable type')."""
    full = TrainingSpec.from_dict(
        {**GOOD, "algorithm": {"preset": "odmtl-3a-10x10", "ppo": {"update_epochs": 3}},
         "selection": {"keep_best": "cost", "eval_every": 2}}
    ).to_dict()
    paths = _paths(full)
    assert ("algorithm", "preset") in paths and len(paths) > 30
    for path in paths:
        for value in _ODD_VALUES:
            try:
                TrainingSpec.from_dict(_replaced(full, path, value))
            except SpecError as exc:
                assert exc.field, (path, value)


def test_experts_of_qos_zero_are_left_out_of_the_demonstration():
    """R_S = QoS / sum QoS never picks an expert of weight 0: the run neither loads it nor
    lists it on the card; plain references (equal weights) all stay."""
    base = {"env": {"rows": 6, "cols": 6}, "budget": {"steps": 100}}
    spec = TrainingSpec.from_dict({**base, "experts": [
        {"model": "m0", "qos": 0}, "m1", {"model": "m2", "qos": 0.5}]})
    demo = spec.demonstration()
    assert demo.experts == ("m1", "m2") and demo.weights == (1.0, 0.5)
    assert spec.experts == ("m0", "m1", "m2")  # the spec itself is what the requester wrote
    plain = TrainingSpec.from_dict({**base, "experts": ["m0", "m1"]}).demonstration()
    assert plain.experts == ("m0", "m1") and plain.weights == (1.0, 1.0)
