"""`drlaas eval`: success rate, time and cost of a model or a baseline, next to the oracle.

Registered by the CLI as ``app.command("eval")(eval_command)``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from workers.mdrl.baselines import BASELINES, OraclePolicy, make_baseline
from workers.mdrl.env import LayoutError
from workers.mdrl.evaluate import MAX_EPISODES, EvalReport, compare, evaluate
from workers.mdrl.review import suggested_review
from workers.mdrl.spec import EnvSpec, IntensitySpec, parse_grid, parse_walls

# flag of each EnvSpec field a user can set here (to name the flag in errors)
_FLAGS = {
    "agents": "--agents",
    "grid": "--grid",
    "walls": "--walls",
    "intensity": "--intensity",
    "moves": "--moves",
    "readings": "--readings",
}


def build_spec(
    base: EnvSpec,
    agents: int | None = None,
    grid: str | None = None,
    walls: str | None = None,
    intensity: str | None = None,
    moves: int | None = None,
    readings: str | None = None,
) -> EnvSpec:
    """``base`` with the flags applied; bad values raise ``typer.BadParameter`` naming the flag."""
    changes: dict[str, Any] = {}
    if agents is not None:
        if agents < 1:
            raise typer.BadParameter(f"must be >= 1, got {agents}", param_hint="--agents")
        changes["agents"] = agents
    if grid is not None:
        try:
            rows, cols = parse_grid(grid)
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--grid") from None
        if rows < 2 or cols < 2:
            raise typer.BadParameter(
                f"grid must be at least 2x2, got {grid!r}", param_hint="--grid"
            )
        changes["rows"], changes["cols"] = rows, cols
    if walls is not None:
        try:
            lo, hi = parse_walls(walls)
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--walls") from None
        if not 0 <= lo <= hi:
            raise typer.BadParameter(
                f"expected 0 <= min <= max, got {walls!r}", param_hint="--walls"
            )
        changes["walls"] = (lo, hi)
    if intensity is not None:
        try:
            changes["intensity"] = IntensitySpec.parse(intensity)
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--intensity") from None
    if moves is not None:
        if moves not in (4, 8):
            raise typer.BadParameter(f"must be 4 or 8, got {moves}", param_hint="--moves")
        changes["moves"] = moves
    if readings is not None:
        if readings not in ("poisson", "expected"):
            raise typer.BadParameter(
                f"must be poisson or expected, got {readings!r}", param_hint="--readings"
            )
        changes["readings"] = readings
    try:
        return base.replace(**changes)
    except ValueError as exc:  # combinations (agents vs grid, walls vs grid size)
        text = str(exc)
        hints = [flag for key, flag in _FLAGS.items() if key in text and key in _given(changes)]
        raise typer.BadParameter(text, param_hint=" / ".join(hints) or None) from None


def _given(changes: dict[str, Any]) -> set[str]:
    keys = set(changes)
    if "rows" in keys:
        keys.add("grid")
    return keys


def model_policy_for(path: Path, spec: EnvSpec | None, card_spec: EnvSpec, policy: Any) -> Any:
    """The loaded model's policy rebuilt for ``spec``; rejects specs its actor cannot take.

    The actor fixes its input shape and output size. The wall channels are pinned to what the
    model was trained with, so a wall-blind model can still be run (blind) among walls.
    """
    from workers.mdrl.modelio import GreedyPolicy
    from workers.mdrl.observations import make_observer
    from workers.mdrl.rollout import PolicyHead

    if spec is None or spec == card_spec:
        return policy
    trained = policy.observer
    obs_spec = trained.obs_spec.__class__(**{**trained.obs_spec.to_dict(), "walls": trained.walls})
    differs = [flag for key, flag in _FLAGS.items() if _field(spec, key) != _field(card_spec, key)]
    flags = " / ".join(differs) or None
    try:
        observer = make_observer(spec, obs_spec, any_window=True)  # a larger map's model too
    except ValueError as exc:
        raise typer.BadParameter(
            f"model {path} cannot take this environment: {exc}", param_hint=flags
        ) from None
    head = PolicyHead(spec.num_actions, spec.agents, joint=bool(observer.joint_actions))
    if (
        observer.actor_shape != trained.actor_shape
        or head.policy_actions != policy.head.policy_actions
    ):
        raise typer.BadParameter(
            f"model {path} ({trained.kind.upper()}, trained on {card_spec.agents} agents, "
            f"{card_spec.rows}x{card_spec.cols}, {card_spec.moves} moves) has an actor with input "
            f"{trained.actor_shape} and {policy.head.policy_actions} outputs; this environment "
            f"needs {observer.actor_shape} and {head.policy_actions}",
            param_hint=flags,
        )
    rebuilt = GreedyPolicy(policy.agent, observer, head)
    rebuilt.card = policy.card
    rebuilt.env_spec = spec
    return rebuilt


def _field(spec: EnvSpec, key: str) -> Any:
    return (spec.rows, spec.cols) if key == "grid" else getattr(spec, key)


def _show(spec: EnvSpec, key: str) -> str:
    if key == "grid":
        return f"{spec.rows}x{spec.cols} (cells of {min(spec.cell_size_m):.3g} m)"
    if key == "walls":
        return f"{spec.walls[0]}-{spec.walls[1]}"
    return str(_field(spec, key))


def setting_changes(policy: Any, spec: EnvSpec) -> list[str]:
    """How ``spec`` differs from the environment a loaded model was trained on, one
    ``--flag trained -> now`` a difference (empty for a baseline or the card's own
    environment); a wall-blind model among walls is said to be blind. ``drlaas eval`` prints
    them: a model run on another grid, team, walls or intensity scored without a word."""
    card_spec = getattr(policy, "env_spec", None)
    card = getattr(policy, "card", None)
    if card_spec is None or not isinstance(card, dict):
        return []
    trained = card.get("env")
    trained = EnvSpec.from_dict(trained) if isinstance(trained, dict) else card_spec
    changes = [f"{flag} {_show(trained, key)} -> {_show(spec, key)}"
               for key, flag in _FLAGS.items() if _field(spec, key) != _field(trained, key)]
    observer = getattr(policy, "observer", None)
    if (spec.walls != trained.walls and spec.walls[1] > 0 and observer is not None
            and not getattr(observer, "walls", True)):
        changes.append("the model has no wall inputs: it moves blind to the walls")
    return changes


def resolve_policy(
    name: str, agents=None, grid=None, walls=None, intensity=None, moves=None, seed: int = 0,
    readings: str | None = None, as_expert: bool = False,
) -> tuple[Any, EnvSpec, str]:
    """(policy, env spec, label) for a baseline name or a model directory plus flags."""
    if as_expert:
        return resolve_expert(name, agents, grid, walls, intensity, moves, seed, readings)
    if name in BASELINES:
        spec = build_spec(EnvSpec(), agents, grid, walls, intensity, moves, readings)
        return make_baseline(name, seed=seed), spec, name
    policy = _load_model_dir(name, f"a baseline ({', '.join(BASELINES)})")
    card_spec = policy.env_spec
    spec = build_spec(card_spec, agents, grid, walls, intensity, moves, readings)
    return model_policy_for(Path(name), spec, card_spec, policy), spec, str(Path(name))


def _load_model_dir(name: str, else_what: str) -> Any:
    """The model in directory ``name``; anything else is a usage error naming --policy (what
    else ``name`` could have been, a run directory's models, or why the model did not load)."""
    path = Path(name)
    if not path.is_dir():
        raise typer.BadParameter(
            f"{name!r} is neither {else_what} nor a model directory", param_hint="--policy"
        )
    from workers.mdrl.modelio import CARD, load_model

    if not (path / CARD).is_file():
        _refuse_run_dir(path)
    try:
        return load_model(path)
    except (OSError, ValueError, KeyError, RuntimeError) as exc:
        raise typer.BadParameter(
            f"cannot load model {name!r}: {exc}", param_hint="--policy"
        ) from None


def resolve_expert(
    name: str, agents=None, grid=None, walls=None, intensity=None, moves=None, seed: int = 0,
    readings: str | None = None,
) -> tuple[Any, EnvSpec, str]:
    """(policy, env spec, label) for ``name`` run as an expert (``FollowExpert``) on the
    environment of the flags: any model the MEDC adapter takes, whatever its team size, grid
    or inputs, and the built-in experts (faulty ones too). The flags start from the model's
    environment (a built-in's: the default one)."""
    from workers.mdrl.experts import BUILTINS, ExpertError, FollowExpert, load_expert

    base = EnvSpec()
    if name not in BUILTINS and not name.startswith(("biased:", "malicious:")):
        base = _load_model_dir(name, f"an expert ({', '.join(BUILTINS)})").env_spec
    spec = build_spec(base, agents, grid, walls, intensity, moves, readings)
    try:
        load_expert(name, spec, seed)  # the adapter's refusals, before any episode
    except ExpertError as exc:
        raise typer.BadParameter(str(exc), param_hint="--policy") from None
    label = f"{name} (as expert)"
    return FollowExpert(name, seed, label), spec, label


def _refuse_run_dir(path: Path) -> None:
    """A `drlaas train` output directory was refused with only "no model.json": name the
    models it holds (model/, the final one, and best/ with --keep-best) to give instead.
    Not picked silently, since model/ and best/ are different policies."""
    from workers.mdrl.modelio import CARD

    held = [path / sub for sub in ("model", "best") if (path / sub / CARD).is_file()]
    if held:
        choices = " or ".join(f"--policy {p}" for p in held)
        raise typer.BadParameter(
            f"{path} is a training run directory, not a model directory: give {choices}"
            + (" (best/: the best evaluated policy)" if len(held) > 1 else ""),
            param_hint="--policy",
        )


def _fmt_ci(ci: list) -> str:
    lo, hi = ci
    return "n/a" if lo is None or lo != lo else f"[{lo:.2f}, {hi:.2f}]"


def _lines(label: str, r: EvalReport) -> list[str]:
    s = r.summary
    return [
        f"{label}: success {100 * s['success_rate']:.1f}% "
        f"[{100 * s['success_ci'][0]:.1f}, {100 * s['success_ci'][1]:.1f}]  "
        f"time {s['time_mean']:.2f} {_fmt_ci(s['time_ci'])}  "
        f"cost {s['cost_mean']:.2f} {_fmt_ci(s['cost_ci'])}"
    ]


def eval_command(
    policy: Annotated[
        str,
        typer.Option(
            "--policy", help="baseline (random, uniform, bayes, oracle) or a model "
            "directory (a training run's model/ or best/)"
        ),
    ],
    agents: Annotated[
        int | None, typer.Option(help="number of agents (default: 3, or the model's)")
    ] = None,
    grid: Annotated[str | None, typer.Option(
        help="ROWSxCOLS, e.g. 10x10, over the same area (the model's area_m): more cells are "
             "smaller cells")] = None,
    walls: Annotated[
        str | None, typer.Option(help="walls per episode: a count (0) or a range (1-3)")
    ] = None,
    intensity: Annotated[
        str | None, typer.Option(help="photons/min: 1e9, a set 1e8,5e8,1e9 or a range 1e8:1e9")
    ] = None,
    episodes: Annotated[int, typer.Option(min=1, max=MAX_EPISODES, help="seeded test episodes")
                        ] = 1000,
    seed: Annotated[int, typer.Option(min=0, help="seed of the episode layouts")] = 0,
    moves: Annotated[int | None, typer.Option(help="4 or 8 directions (+ idle)")] = None,
    batch: Annotated[int | None, typer.Option(
        min=1, help="environments stepped together; episodes are seeded per batch, so compare "
        "runs at the same --seed, --episodes and --batch")] = None,
    readings: Annotated[
        str | None,
        typer.Option(help="reading model: poisson (product default) or expected (noise-free "
                     "counts, what thesis Tables 3.5/3.6 compare with); default: the model's"),
    ] = None,
    as_expert: Annotated[bool, typer.Option(
        "--as-expert", help="run --policy as an MEDC expert: every agent takes its best-ranked "
        "valid action through the expert adapter, so a model trained on another team size, "
        "grid or input set can be reviewed on this environment; also the built-in experts "
        "(oracle, bayes, uniform, random, biased:K, malicious:REF)")] = False,
    json_out: Annotated[bool, typer.Option("--json", help="print one JSON object")] = False,
) -> None:
    """Evaluate a model directory or a baseline on seeded episodes, next to the oracle."""
    pol, spec, label = resolve_policy(policy, agents, grid, walls, intensity, moves, seed, readings,
                                      as_expert)
    changes = [] if as_expert else setting_changes(pol, spec)
    if changes:  # stderr, before the episodes run: stdout stays the report (--json: one object)
        training = pol.card.get("training")
        mixed = isinstance(training, dict) and bool(training.get("generalist"))
        than = ("the set-up its card names (a generalist: its card lists the set-ups it "
                "trained on)" if mixed else "it was trained on")
        typer.echo(f"note: {label} is evaluated on another environment than {than}: "
                   f"{'; '.join(changes)}", err=True)
    try:
        report = evaluate(pol, spec, episodes, seed=seed, batch=batch, name=label)
    except LayoutError as exc:  # walls the spec allows but no layout can hold the team with
        raise typer.BadParameter(str(exc), param_hint="--walls") from None
    oracle = evaluate(OraclePolicy(), spec, episodes, seed=seed, batch=batch, name="oracle")
    ratios = compare(report, oracle)
    # a review of the model as this task's expert (MMC updateModelRep takes 0-5)
    suggested = suggested_review(report.success_rate, ratios.time_ratio) if as_expert else None
    if json_out:
        out = {
            "policy": label,
            "env": spec.to_dict(),
            "episodes": episodes,
            "seed": seed,
            "result": {k: v for k, v in report.to_dict().items() if k != "env"},
            "oracle": {k: v for k, v in oracle.to_dict().items() if k != "env"},
            "ratios": ratios.to_dict(),
            **({"trained_env": pol.card["env"], "differs_from_training": changes}
               if changes else {}),
            **({"suggested_review": suggested} if as_expert else {}),
        }
        typer.echo(json.dumps(out))
        return
    typer.echo(
        f"{episodes} episodes, seed {seed}: {spec.agents} agents, {spec.rows}x{spec.cols}, "
        f"{spec.moves} moves, walls {spec.walls[0]}-{spec.walls[1]}, intensity {spec.intensity}, "
        f"{spec.readings} readings"
    )
    for line in _lines(label, report) + _lines("oracle", oracle):
        typer.echo(line)
    typer.echo(
        f"ratio to oracle: time {ratios.time_ratio:.2f} {_fmt_ci(list(ratios.time_ratio_ci))}  "
        f"cost {ratios.cost_ratio:.2f} {_fmt_ci(list(ratios.cost_ratio_ci))}  (95% CI: Wilson for "
        f"rates, Student t for means, paired bootstrap for ratios)"
    )
    if suggested is not None:
        typer.echo(f"suggested review as this task's expert: {suggested}/5 (5 x success x oracle "
                   f"time / time, rounded; drlaas model review ... --review {suggested})")
