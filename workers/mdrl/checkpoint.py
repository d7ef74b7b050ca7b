"""Checkpoints that resume training identically: tensors in safetensors, the rest in JSON.

A checkpoint directory holds `state.safetensors` (network weights, Adam moments, the torch
Generator state, trainer arrays) plus `env.safetensors` (the env's mid-episode numpy arrays)
and `state.json` (config, counters, Adam scalars, numpy Generator states of the env). Loading
uses safetensors + json only: never torch.save / pickle.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.numpy import load_file as load_numpy
from safetensors.numpy import save_file as save_numpy
from safetensors.torch import load_file as load_torch
from safetensors.torch import save_file as save_torch

FORMAT = "drlaas-checkpoint/1"
_JSON_SCALARS = (bool, int, float, str, type(None))


# ---------------------------------------------------------------- optimizer
def optimizer_to_parts(optimizer: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], dict]:
    """Split an optimizer state_dict into tensors (moments, step) and JSON (param groups)."""
    sd = optimizer.state_dict()
    tensors: dict[str, torch.Tensor] = {}
    scalars: dict[str, dict[str, Any]] = {}
    for idx, st in sd["state"].items():
        for key, val in st.items():
            if isinstance(val, torch.Tensor):
                tensors[f"optim/{idx}/{key}"] = val.detach().clone().contiguous()
            else:
                scalars.setdefault(str(idx), {})[key] = val
    groups = [{k: (list(v) if isinstance(v, tuple) else v) for k, v in g.items()}
              for g in sd["param_groups"]]
    return tensors, {"param_groups": groups, "scalars": scalars}


def optimizer_from_parts(optimizer: torch.optim.Optimizer, tensors: dict[str, torch.Tensor],
                         meta: dict) -> None:
    """Inverse of `optimizer_to_parts`: load moments, step counts and param groups."""
    state: dict[int, dict[str, Any]] = {}
    for name, val in tensors.items():
        if not name.startswith("optim/"):
            continue
        _, idx, key = name.split("/", 2)
        state.setdefault(int(idx), {})[key] = val
    for idx, extra in meta.get("scalars", {}).items():
        state.setdefault(int(idx), {}).update(extra)
    groups = []
    for g in meta["param_groups"]:
        g = dict(g)
        if "betas" in g:
            g["betas"] = tuple(g["betas"])
        groups.append(g)
    state = {k: state[k] for k in sorted(state)}
    optimizer.load_state_dict({"state": state, "param_groups": groups})


# ---------------------------------------------------------------- environment
def env_state(env: Any) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Everything an env needs to continue mid-episode: arrays, RNG states, scalar counters.

    Uses `env.state_dict()` when the env has it (it returns (arrays, json_dict)); otherwise
    it walks the env's attributes: numpy arrays -> arrays, numpy Generators ->
    `bit_generator.state` (JSON), JSON scalars -> JSON. Other attributes (the spec, caches
    rebuilt from it) are not saved and must not change during training.
    """
    if hasattr(env, "state_dict"):
        arrays, meta = env.state_dict()
        return dict(arrays), {"state_dict": meta}
    arrays: dict[str, np.ndarray] = {}
    rngs: dict[str, Any] = {}
    scalars: dict[str, Any] = {}
    for name, val in vars(env).items():
        if isinstance(val, np.ndarray):
            arrays[name] = np.ascontiguousarray(val)
        elif isinstance(val, np.random.Generator):
            rngs[name] = val.bit_generator.state
        elif isinstance(val, _JSON_SCALARS):
            scalars[name] = val
        elif isinstance(val, np.generic):
            scalars[name] = val.item()
    return arrays, {"rngs": rngs, "scalars": scalars}


def restore_env_state(env: Any, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    """Inverse of `env_state`, in place (arrays are copied into the existing buffers)."""
    if "state_dict" in meta:
        if not hasattr(env, "load_state_dict"):
            raise ValueError("checkpoint holds an env state_dict; the env has no load_state_dict")
        env.load_state_dict(arrays, meta["state_dict"])
        return
    for name, arr in arrays.items():
        cur = getattr(env, name, None)
        if not isinstance(cur, np.ndarray):
            raise ValueError(f"checkpoint env array {name!r} does not match an env array")
        if cur.shape == arr.shape and cur.dtype == arr.dtype:
            cur[...] = arr
        else:
            setattr(env, name, arr.copy())
    for name, st in meta["rngs"].items():
        rng = getattr(env, name, None)
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"checkpoint env RNG {name!r} is not a numpy Generator on the env")
        rng.bit_generator.state = st
    for name, val in meta["scalars"].items():
        setattr(env, name, val)


# ---------------------------------------------------------------- files
def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_tree(root: Path) -> None:
    """fsync every file and directory under ``root`` (``root`` included), deepest first: a
    rename only makes data durable that is on disk already (after a power cut a renamed file
    written without fsync can be empty)."""
    for dirpath, _, files in os.walk(root, topdown=False):
        for name in files:
            _fsync(Path(dirpath, name))
        _fsync(Path(dirpath))


def restore_swapped(path: str | Path) -> bool:
    """Put back ``<path>.old`` as ``path`` when a process was killed between the two renames
    of :func:`atomic_dir` (the last whole directory is then only the ``.old`` one, which no
    reader looked at: "cannot resume"). Returns whether it did."""
    path = Path(path)
    old = path.with_name(path.name + ".old")
    if path.exists() or not (old / "state.json").is_file():
        return False
    os.replace(old, path)
    return True


@contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a fresh temp dir beside ``path``; on success swap it in for ``path`` (the old one
    moves aside first), so a crash leaves the previous directory whole: ``path``, or
    ``<path>.old`` when it came between the two renames. Everything is fsynced before the
    swap and the parent after it, so an OS crash or power cut leaves one of them whole too."""
    path = Path(path)
    tmp, old = path.with_name(path.name + ".tmp"), path.with_name(path.name + ".old")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    yield tmp
    fsync_tree(tmp)
    if path.exists():
        if old.exists():
            shutil.rmtree(old)
        os.replace(path, old)
    os.replace(tmp, path)
    _fsync(path.parent)
    if old.exists():
        shutil.rmtree(old)


def save_checkpoint(path: str | Path, tensors: dict[str, torch.Tensor],
                    env_arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Path:
    """Write a checkpoint directory atomically (``atomic_dir``)."""
    with atomic_dir(path) as tmp:
        save_torch({k: v.detach().contiguous() for k, v in tensors.items()},
                   str(tmp / "state.safetensors"))
        save_numpy({k: np.ascontiguousarray(v) for k, v in env_arrays.items()},
                   str(tmp / "env.safetensors"))
        doc = {"format": FORMAT, **meta}
        (tmp / "state.json").write_text(json.dumps(doc, indent=1, sort_keys=True))
    return Path(path)


def load_checkpoint(path: str | Path) -> tuple[dict[str, torch.Tensor], dict[str, np.ndarray],
                                                 dict[str, Any]]:
    """Read a checkpoint directory: (tensors, env arrays, meta). safetensors + json only."""
    path = Path(path)
    files = [path / "state.safetensors", path / "env.safetensors", path / "state.json"]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise FileNotFoundError(f"not a checkpoint directory {path}: missing {missing}")
    try:
        meta = json.loads(files[2].read_text())
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError is a ValueError
        raise ValueError(f"{files[2]}: not a JSON checkpoint state ({exc})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{files[2]}: expected a JSON object, got {type(meta).__name__}")
    if meta.get("format") != FORMAT:
        raise ValueError(f"{files[2]}: unknown checkpoint format {meta.get('format')!r}")
    loaded = []
    for file, load in ((files[0], load_torch), (files[1], load_numpy)):
        try:
            loaded.append(load(str(file)))
        except SafetensorError as exc:  # truncated or damaged
            raise ValueError(f"{file}: not a readable safetensors file ({exc})") from None
    return loaded[0], loaded[1], meta
