"""`drlaas train`: train an MDRL model with PPO from a preset, a config file or a platform task's
spec (what a worker would train for it, on this machine)."""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

MODEL_FETCHER: Callable[[str, str], Path] | None = None
"""(model CID, "expert" | "walls CAE") -> its verified local directory: how `drlaas train` uses an
expert or a walls CAE named by CID. The core alone has none (it trains from directories and
built-ins); the platform CLI (drlaas/cli.py) sets one that fetches through the gateway and
verifies as a worker does (workers/daemon/experts.py)."""


def _out_path(text: str) -> Path:
    """--out: a directory path; an empty one (the current directory by accident) is refused."""
    if not text.strip():
        raise typer.BadParameter("must name a directory, got an empty path")
    return Path(text)


RUN_FLAGS = {"total_steps": "--steps", "minutes": "--minutes", "seed": "--seed",
             "eval_every": "--eval-every", "eval_episodes": "--eval-episodes",
             "checkpoint_every": "--checkpoint-every", "threads": "--threads",
             "keep_best": "--keep-best", "init_from": "--init-from"}
"""The flag of each RunConfig field the command sets (to name it in errors)."""

RUN_FILES = ("checkpoint", "model", "metrics.csv")
"""What makes a directory hold a run: --out refuses to write a new run over them."""
RUN_DIRS, RUN_PLAIN = ("checkpoint", "model", "best", "tb"), ("metrics.csv", "config.json")
"""What a run writes into --out as directories and as files: one of another kind in the way
would fail mid-run (after the first update's rows were written)."""


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _check_flags(given: dict[str, Any]) -> None:
    """The run flags given on the command line, checked by RunConfig before anything is built
    (BadParameter naming the flag); --threads also against this machine's CPUs."""
    from workers.mdrl.train import RunConfig, RunConfigError

    try:
        RunConfig.from_dict(given)
    except RunConfigError as exc:
        raise typer.BadParameter(str(exc), param_hint=RUN_FLAGS.get(exc.field)) from None
    threads, cpus = given.get("threads", 1), usable_cpus()
    if threads > cpus:
        raise typer.BadParameter(f"must be between 1 and {cpus} (the CPUs this process may use; "
                                 f"more threads only contend), got {threads}",
                                 param_hint="--threads")


def _check_out(out: Path, *, same_run: Path | None = None) -> None:
    """Refuse an --out that cannot be a run directory before anything is built or written: a
    file, a path under a file, a place where no directory can be made, or a directory that
    already holds a run (unless it is ``same_run``, the run being resumed)."""
    if out.exists():
        if not out.is_dir():
            raise typer.BadParameter(f"{out} is a file, not a directory", param_hint="--out")
        if (out / "model.json").is_file():  # the run would write beside the model's files
            raise typer.BadParameter(f"{out} is a model directory (model.json): give a new "
                                     "directory for the run", param_hint="--out")
        held = [name for name in RUN_FILES if (out / name).exists()]
        same = same_run is not None and out.resolve() == same_run.resolve()
        if held and not same:
            raise typer.BadParameter(
                f"{out} already holds a run ({', '.join(held)}): continue it with --resume "
                f"{out}, or give another --out", param_hint="--out")
        blocked = [f"{n} (a file)" for n in RUN_DIRS if (out / n).exists()
                   and not (out / n).is_dir()]
        blocked += [f"{n} (a directory)" for n in RUN_PLAIN if (out / n).is_dir()]
        if blocked:
            raise typer.BadParameter(
                f"{out} holds {', '.join(blocked)} where the run writes its own: move it or "
                "give another --out", param_hint="--out")
    parent = out
    while not parent.exists():  # the nearest existing ancestor must take a new directory
        parent = parent.parent
    if not parent.is_dir():
        raise typer.BadParameter(f"cannot make {out}: {parent} is a file, not a directory",
                                 param_hint="--out")
    try:  # the one reliable test (permissions, read-only or special file systems)
        os.rmdir(tempfile.mkdtemp(prefix=".drlaas-out-", dir=parent))
    except OSError as exc:
        raise typer.BadParameter(f"cannot write {out}: {exc.strerror or exc} in {parent}",
                                 param_hint="--out") from None


def _list_presets(value: bool) -> None:
    """--list-presets: each preset's name and description, one a line, then exit (the help
    can only name the families)."""
    if not value:
        return
    from workers.mdrl.presets import PRESETS

    width = max(map(len, PRESETS))
    for name, chosen in PRESETS.items():
        typer.echo(f"{name:{width}}  {chosen.description}")
    raise typer.Exit()


def _check_resume(resume: Path) -> None:
    """--resume names an existing run directory (or its checkpoint/) holding a checkpoint:
    checked before anything else, since the budget or other options mean nothing without
    one (a missing directory was reported as a missing budget)."""
    if not resume.is_dir():
        raise typer.BadParameter(f"{resume}: no such directory", param_hint="--resume")
    if (resume / "model.json").is_file() and not (resume / "state.json").is_file():
        raise typer.BadParameter(f"{resume} is a model directory; --resume takes a run "
                                 "directory (holding checkpoint/) or its checkpoint/",
                                 param_hint="--resume")
    places = (resume, resume / "checkpoint", resume / "checkpoint.old")  # .old: killed saving
    if not any((p / "state.json").is_file() for p in places):
        raise typer.BadParameter(f"{resume} is not a checkpoint directory and holds no "
                                 "checkpoint/ (a run directory of `drlaas train --out`)",
                                 param_hint="--resume")


def _nothing_left(trainer) -> str | None:
    """Why a resumed run has no budget left (its steps or time already reach the given
    ones), or None: the run would end at once with its old summary, which read as done."""
    run, used = trainer.run, []  # (what the run has, its budget, the flag)
    if run.total_steps is not None and trainer.global_step >= run.total_steps:
        used.append((f"{trainer.global_step} steps", f"{run.total_steps}", "--steps"))
    if run.minutes is not None and trainer.elapsed >= run.minutes * 60.0:
        used.append((f"{trainer.elapsed / 60:.2f} minutes", f"{run.minutes:g}", "--minutes"))
    if not used:
        return None
    has = (f"{used[0][0]}, its budget is {used[0][1]}" if len(used) == 1
           else " and ".join(f"{what} (budget {budget})" for what, budget, _ in used))
    return (f"nothing to train: the run already has {has}; give a larger "
            f"{' and '.join(flag for *_, flag in used)}")


def train(
    preset: Annotated[str, typer.Option(help="Named set-up, e.g. odmtl-3a-10x10; "
                                             "--list-presets lists them.")] = "odmtl-3a-10x10",
    config: Annotated[Path | None, typer.Option(help="JSON/TOML config file (sections env, "
                                                     "observation, ppo, run); overrides --preset."
                                                )] = None,
    task: Annotated[Path | None, typer.Option(help="A platform task's spec (drlaas-task/1 JSON, "
                                                   "`drlaas task show ID --spec`): train what a "
                                                   "worker trains for it (env, observation, PPO, "
                                                   "budget, seed, experts, selection); "
                                                   "--steps, --minutes and --seed override "
                                                   "it.")
                                ] = None,
    steps: Annotated[int | None, typer.Option(help="Env-step budget of the run (total, "
                                                   "including steps before a resume).")] = None,
    minutes: Annotated[float | None, typer.Option(help="Wall-clock budget in minutes (total, "
                                                       "including time before a resume).")] = None,
    seed: Annotated[int | None, typer.Option(help="Seed of envs, network init and sampling "
                                                  "(default 0, or the --task spec's).")] = None,
    out: Annotated[Path | None, typer.Option(parser=_out_path, metavar="PATH",
                                             help="Output directory (metrics.csv, tb/, "
                                                  "checkpoint/, model/); must not hold a run "
                                                  "yet (default runs/NAME-sSEED).")] = None,
    resume: Annotated[Path | None, typer.Option(help="Continue the run in this directory (or "
                                                     "checkpoint directory).")] = None,
    num_envs: Annotated[int | None, typer.Option(help="Override PPO num_envs.")] = None,
    readings: Annotated[str | None, typer.Option(help="Reading model of the training env: "
                                                     "poisson (default) or expected.")] = None,
    eval_every: Annotated[int | None, typer.Option(help="Greedy evaluation every K updates.")
                          ] = None,
    eval_episodes: Annotated[int | None, typer.Option(help="Evaluation episodes.")] = None,
    checkpoint_every: Annotated[int | None, typer.Option(help="Checkpoint every K updates.")
                                ] = None,
    keep_best: Annotated[str | None, typer.Option(help="Also keep the best evaluated policy as "
                                                       "OUT/best: 'time' (shortest mean "
                                                       "episode) or 'cost' (lowest moving "
                                                       "cost) on the evaluation episodes.")
                         ] = None,
    init_from: Annotated[Path | None, typer.Option(help="Start from this model's weights "
                                                        "(fine-tuning; same observation, team "
                                                        "size and actions).")] = None,
    threads: Annotated[int, typer.Option(help="torch threads (1 to the CPU count; fixed for "
                                              "reproducibility).")] = 1,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
    tensorboard: Annotated[bool, typer.Option(help="Write TensorBoard event files.")] = True,
    experts: Annotated[str | None, typer.Option(help="DC / MEDC experts, comma-separated: model "
                                                     "directories or built-ins (oracle, bayes, "
                                                     "random, biased:K, malicious:REF).")] = None,
    expert_qos: Annotated[str | None, typer.Option(help="QoS weight per expert, comma-separated "
                                                        "(R_S = QoS / sum QoS); default equal.")
                          ] = None,
    expert_rate: Annotated[float | None, typer.Option(help="R_E: share of expert-guided "
                                                           "episodes; default 0.2 for one expert "
                                                           "(Table 4.1), 0.1 for several (5.3).")
                           ] = None,
    expert_rate_end: Annotated[float | None, typer.Option(help="R_E at the end of the --steps "
                                                               "budget, reached linearly from "
                                                               "--expert-rate (default: R_E "
                                                               "fixed, as Alg. 5.1).")
                               ] = None,
    expert_threshold: Annotated[float | None, typer.Option(help="l: follow the expert only on "
                                                                "actions with own probability "
                                                                "> l (default 0.05).")] = None,
    expert_credit: Annotated[bool | None, typer.Option(
        "--expert-credit/--no-expert-credit", help="expert credit (medc.py): experts whose "
        "guided episodes are no shorter than the agents' own fade out (default off, as Alg. "
        "5.1)")] = None,
    list_presets: Annotated[bool, typer.Option(
        "--list-presets", is_eager=True, callback=_list_presets,
        help="List the presets (name and description) and exit.")] = False,
) -> None:
    """Train with PPO (Alg. 3.3); writes metrics, TensorBoard, checkpoints and model files."""
    import dataclasses

    from workers.mdrl.experts import ExpertError
    from workers.mdrl.presets import get_preset, load_config
    from workers.mdrl.train import KEEP_BEST, RunConfig, RunConfigError, Trainer

    if keep_best is not None and keep_best not in KEEP_BEST:
        raise typer.BadParameter(f"must be time or cost, got {keep_best!r}",
                                 param_hint="--keep-best")
    if steps is not None and steps < 1:
        raise typer.BadParameter(f"--steps must be >= 1, got {steps}")
    if minutes is not None and not (math.isfinite(minutes) and minutes > 0):
        raise typer.BadParameter(f"--minutes must be a finite number > 0, got {minutes}")
    # the run flags given: only these override a config's [run], a task's spec or a checkpoint
    given = {key: val for key, val in (
        ("total_steps", steps), ("minutes", minutes), ("seed", seed),
        ("eval_every", eval_every), ("eval_episodes", eval_episodes),
        ("checkpoint_every", checkpoint_every), ("keep_best", keep_best)) if val is not None}
    _check_flags({**given, "threads": threads})
    if task is not None and resume is None:
        _train_task(task, steps=steps, minutes=minutes, seed=seed, out=out, threads=threads,
                    progress=progress, tensorboard=tensorboard, eval_every=eval_every,
                    eval_episodes=eval_episodes, checkpoint_every=checkpoint_every,
                    keep_best=keep_best,
                    others={"--config": config, "--num-envs": num_envs, "--readings": readings,
                            "--init-from": init_from, "--experts": experts,
                            "--expert-qos": expert_qos, "--expert-rate": expert_rate,
                            "--expert-rate-end": expert_rate_end,
                            "--expert-threshold": expert_threshold,
                            "--expert-credit": expert_credit})
        return
    if task is not None:
        raise typer.BadParameter("--resume continues a run as configured; drop --task")
    machine = {"threads": threads, "progress": progress, "tensorboard": tensorboard}
    expert_options = (experts, expert_qos, expert_rate, expert_threshold, expert_credit,
                      expert_rate_end)
    if resume is not None:
        _check_resume(resume)
        if num_envs is not None or config is not None or readings is not None or init_from or any(
                o is not None for o in expert_options) or seed is not None:
            raise typer.BadParameter("--resume continues a run as configured; drop --config, "
                                     "--seed, --num-envs, --readings, --init-from and the "
                                     "--expert* options")
        if steps is None and minutes is None:
            raise typer.BadParameter("give a budget: --steps and/or --minutes (the total, "
                                     "including the steps or time before the resume)")
        run_dir = resume if (resume / "checkpoint").is_dir() else resume.parent
        if out is not None:
            _check_out(out, same_run=run_dir)
        # a resume's budget is the one given now: --steps alone drops an old time budget
        changes = {**given, "total_steps": steps, "minutes": minutes, **machine}
        try:
            trainer = Trainer.resume(resume, out=out, run_overrides=changes,
                                     selector=_resume_selector(resume))
        except (OSError, ValueError, KeyError, TypeError, ExpertError) as exc:
            text = str(exc) if not isinstance(exc, KeyError) else f"incomplete checkpoint ({exc})"
            raise typer.BadParameter(f"cannot resume {resume}: {text}",
                                     param_hint="--resume") from None
        nothing = _nothing_left(trainer)
        if nothing is not None:  # still exit 0 with the summary: the run is as asked
            typer.echo(nothing, err=True)
        _finish(trainer)
        return
    source = "--preset" if config is None else "--config"
    try:
        chosen = get_preset(preset) if config is None else load_config(config)
    except (OSError, ValueError, TypeError, KeyError) as exc:  # the message names the field
        raise typer.BadParameter(str(exc), param_hint=source) from None
    ppo = chosen.ppo
    if num_envs is not None:
        try:
            ppo = dataclasses.replace(ppo, num_envs=num_envs)
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--num-envs") from None
    if readings is not None:
        if readings not in ("poisson", "expected"):
            raise typer.BadParameter(f"must be poisson or expected, got {readings!r}",
                                     param_hint="--readings")
        chosen = dataclasses.replace(chosen, env=chosen.env.replace(readings=readings))
    if init_from is not None:
        given["init_from"] = str(init_from)
    try:
        run = RunConfig.from_dict({**chosen.run, **given, **machine})
    except RunConfigError as exc:  # a flag's value was checked above: the config's is wrong
        raise typer.BadParameter(str(exc), param_hint=RUN_FLAGS.get(exc.field) if exc.field
                                 in given else source) from None
    if run.total_steps is None and run.minutes is None:
        raise typer.BadParameter("give a budget: --steps and/or --minutes (or total_steps / "
                                 "minutes in the config's [run])")
    out = out if out is not None else Path("runs") / f"{chosen.name}-s{run.seed}"
    _check_out(out)
    selector = _selector(chosen, run.seed, *expert_options)
    try:
        trainer = Trainer(chosen.env, chosen.observation, ppo, run, out=out,
                          selector=selector,
                          walls_encoder=_walls_encoder(chosen.observation.walls_embedding))
    except (OSError, ValueError) as exc:  # e.g. --init-from a model that does not fit
        raise typer.BadParameter(str(exc), param_hint="--init-from" if run.init_from
                                 else source) from None
    _finish(trainer)


def _finish(trainer) -> None:
    """Train and print the run's JSON summary (where the model is, how it did); a diverged
    run (NaN/inf loss or weights) is an error without a model (exit code 1)."""
    from workers.mdrl.train import TrainingDiverged

    try:
        summary = trainer.train()
    except TrainingDiverged as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    result = {"out": str(trainer.out), "model": str(trainer.out / "model"),
              "env_steps": trainer.global_step, "updates": trainer.update_idx,
              "wall_time_s": round(trainer.elapsed, 1), **trainer.last_eval,
              "train_success": summary.get("success")}
    if trainer.best is not None:  # --keep-best: where the chosen policy is and how it did
        result["best"] = str(trainer.out / "best")
        result["best_update"] = trainer.best["update"]
        result.update({f"best_{k}": v for k, v in trainer.best.items() if k.startswith("eval_")})
    # JSON has no NaN (a figure with no episode behind it, e.g. a run shorter than an episode)
    typer.echo(json.dumps({k: None if isinstance(v, float) and math.isnan(v) else v
                           for k, v in result.items()}))


# ------------------------------------------------------------------ a platform task's spec
def _train_task(path: Path, *, steps, minutes, seed, out, threads, progress, tensorboard,
                eval_every, eval_episodes, checkpoint_every, keep_best, others) -> None:
    """``--task``: the spec parsed by the platform's own parser and trained with the worker's
    run config (``TrainingSpec.run_config``); experts and a walls CAE named by CID come
    through MODEL_FETCHER, as a worker's are fetched and verified."""
    from workers.mdrl.experts import ExpertError
    from workers.mdrl.medc import DemonstrationSelector
    from workers.mdrl.train import Trainer
    from workers.mdrl.trainingspec import SpecError, TrainingSpec

    given = [name for name, v in others.items() if v is not None]
    if given:
        raise typer.BadParameter(f"--task trains the spec as written; drop {', '.join(given)} "
                                 "(edit the spec instead)")
    try:
        spec = TrainingSpec.from_json(path.read_bytes())
    except OSError as exc:
        raise typer.BadParameter(f"cannot read {path}: {exc}", param_hint="--task") from None
    except SpecError as exc:
        raise typer.BadParameter(f"{path}: {exc}", param_hint="--task") from None
    changes = {"threads": threads, "progress": progress, "tensorboard": tensorboard}
    for key, val in (("total_steps", steps), ("minutes", minutes), ("seed", seed),
                     ("eval_every", eval_every), ("eval_episodes", eval_episodes),
                     ("checkpoint_every", checkpoint_every), ("keep_best", keep_best)):
        if val is not None:
            changes[key] = val
    try:
        run = spec.run_config(**changes)
        out = out if out is not None else Path("runs") / f"{path.stem}-s{run.seed}"
        _check_out(out)  # before experts or a walls CAE are fetched
        demo = spec.demonstration()
        selector = (DemonstrationSelector.from_config(
            demo, spec.env, seed=run.seed, experts=_load_experts(demo.experts, spec.env, run.seed))
            if demo is not None else None)
        encoder = _walls_encoder(spec.observation.walls_embedding)
        trainer = Trainer(spec.env, spec.observation, spec.ppo, run, out=out, selector=selector,
                          walls_encoder=encoder)
    except (OSError, ValueError, ExpertError) as exc:
        raise typer.BadParameter(str(exc), param_hint="--task") from None
    _finish(trainer)


def _is_cid(ref: str) -> bool:
    import re

    from workers.mdrl.trainingspec import SPEC_CID_PATTERN

    return re.fullmatch(SPEC_CID_PATTERN, ref) is not None and not Path(ref).exists()


def _fetched(ref: str, kind: str) -> Path:
    """The verified directory of model CID ``ref`` (MODEL_FETCHER), or a clear error."""
    if MODEL_FETCHER is None:
        raise ValueError(f"{kind} {ref} is a model CID and this `train` fetches nothing: pull it "
                         "(`drlaas model pull`) and name its directory")
    return MODEL_FETCHER(ref, kind)


def _load_experts(refs: tuple[str, ...], env: Any, seed: int) -> list[Any]:
    """The experts, those named by CID fetched (MODEL_FETCHER) and named by their CID as a
    worker names them, so the card lists the CID."""
    from workers.mdrl.experts import load_experts

    return load_experts(refs, env, seed, dirs={r: _fetched(r, "expert") for r in refs
                                               if _is_cid(r)})


def _walls_encoder(ref: str | None) -> Any:
    """A walls CAE named by CID, fetched and named by it (None: loaded by path, or none)."""
    if ref is None or not _is_cid(ref):
        return None
    from workers.mdrl.cae import WallsEmbedder, load_cae

    return WallsEmbedder(load_cae(_fetched(ref, "walls CAE")).encoder, ref)


# ------------------------------------------------------------------ experts (DC / MEDC)
def _selector(chosen, seed, experts, qos, rate, threshold, credit, rate_end):
    """The DC / MEDC selector from the config's [experts] section and the --expert* options
    (--experts replaces the section's models and their QoS), or None without experts."""
    import dataclasses

    from workers.mdrl.experts import ExpertError
    from workers.mdrl.medc import DemonstrationConfig, DemonstrationSelector, parse_list

    demo = chosen.experts
    try:
        if experts is not None:  # new models, the section's other settings kept
            models = tuple(parse_list(experts, "--experts"))
            demo = (DemonstrationConfig(models) if demo is None
                    else dataclasses.replace(demo, experts=models, qos=()))
        if demo is None:
            if any(o is not None for o in (qos, rate, threshold, credit, rate_end)):
                raise typer.BadParameter("--expert-qos/--expert-rate/--expert-rate-end/"
                                         "--expert-threshold/--expert-credit need --experts "
                                         "(or an [experts] section in --config)")
            return None
        changes = {}
        if qos is not None:
            try:
                changes["qos"] = tuple(float(q) for q in parse_list(qos, "--expert-qos"))
            except ValueError as exc:
                raise ValueError(f"--expert-qos: expected numbers, got {qos!r} ({exc})") from None
        if rate is not None:
            changes["rate"] = rate
        if threshold is not None:
            changes["threshold"] = threshold
        if credit is not None:
            changes["credit"] = credit
        if rate_end is not None:
            changes["rate_end"] = rate_end
        demo = dataclasses.replace(demo, **changes)
        return DemonstrationSelector.from_config(
            demo, chosen.env, seed=seed, experts=_load_experts(demo.experts, chosen.env, seed))
    except ExpertError as exc:  # a model that cannot guide: named by the flag or the file
        raise typer.BadParameter(str(exc), param_hint="--experts" if experts is not None
                                 else "--config") from None
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None


def _resume_selector(path: Path):
    """Rebuild the expert selector a checkpointed run used (its state is restored after)."""
    from workers.mdrl.medc import resume_selector

    path = path / "checkpoint" if (path / "checkpoint").is_dir() else path
    meta_file = path / "state.json"
    if not meta_file.is_file():
        return None  # Trainer.resume reports the missing checkpoint
    try:
        meta = json.loads(meta_file.read_text())
    except (UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{meta_file}: not a JSON checkpoint state ({exc})") from None
    if not isinstance(meta, dict):
        return None  # Trainer.resume names it
    return resume_selector(meta)
