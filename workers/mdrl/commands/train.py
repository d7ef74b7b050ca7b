"""`drlaas train`: train an MDRL model with PPO from a preset or a config file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer


def train(
    preset: Annotated[str, typer.Option(help="Named set-up, e.g. odmtl-3a-10x10 "
                                             "(see workers/mdrl/presets.py).")] = "odmtl-3a-10x10",
    config: Annotated[Path | None, typer.Option(help="JSON/TOML config file (sections env, "
                                                     "observation, ppo, run); overrides --preset."
                                                )] = None,
    steps: Annotated[int | None, typer.Option(help="Env-step budget of the run (total, "
                                                   "including steps before a resume).")] = None,
    minutes: Annotated[float | None, typer.Option(help="Wall-clock budget in minutes (total, "
                                                       "including time before a resume).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of envs, network init and sampling.")] = 0,
    out: Annotated[Path | None, typer.Option(help="Output directory (metrics.csv, tb/, "
                                                  "checkpoint/, model/).")] = None,
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
    threads: Annotated[int, typer.Option(help="torch threads (1-2; fixed for reproducibility).")
                       ] = 1,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
    tensorboard: Annotated[bool, typer.Option(help="Write TensorBoard event files.")] = True,
) -> None:
    """Train with PPO (Alg. 3.3); writes metrics, TensorBoard, checkpoints and model files."""
    import dataclasses

    from workers.mdrl.presets import get_preset, load_config
    from workers.mdrl.train import RunConfig, Trainer

    if steps is None and minutes is None:
        raise typer.BadParameter("give a budget: --steps and/or --minutes")
    if steps is not None and steps < 1:
        raise typer.BadParameter(f"--steps must be >= 1, got {steps}")
    if minutes is not None and minutes <= 0:
        raise typer.BadParameter(f"--minutes must be > 0, got {minutes}")
    run_changes = {"total_steps": steps, "minutes": minutes, "threads": threads,
                   "progress": progress, "tensorboard": tensorboard}
    for key, val in (("eval_every", eval_every), ("eval_episodes", eval_episodes),
                     ("checkpoint_every", checkpoint_every)):
        if val is not None:
            run_changes[key] = val
    if resume is not None:
        if num_envs is not None or config is not None or readings is not None:
            raise typer.BadParameter("--resume continues a run as configured; drop --config, "
                                     "--num-envs and --readings")
        trainer = Trainer.resume(resume, out=out, run_overrides=run_changes)
    else:
        chosen = load_config(config) if config is not None else get_preset(preset)
        ppo = chosen.ppo
        if num_envs is not None:
            ppo = dataclasses.replace(ppo, num_envs=num_envs)
        if readings is not None:
            if readings not in ("poisson", "expected"):
                raise typer.BadParameter(f"must be poisson or expected, got {readings!r}",
                                         param_hint="--readings")
            chosen = dataclasses.replace(chosen, env=chosen.env.replace(readings=readings))
        run = RunConfig.from_dict({**chosen.run, **run_changes, "seed": seed})
        out = out if out is not None else Path("runs") / f"{chosen.name}-s{seed}"
        trainer = Trainer(chosen.env, chosen.observation, ppo, run, out=out,
                          warm=chosen.warm_start)
    summary = trainer.train()
    result = {"out": str(trainer.out), "model": str(trainer.out / "model"),
              "env_steps": trainer.global_step, "updates": trainer.update_idx,
              "wall_time_s": round(trainer.elapsed, 1), **trainer.last_eval,
              "train_success": summary.get("success")}
    typer.echo(json.dumps(result))
