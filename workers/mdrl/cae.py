"""Walls convolutional autoencoder (thesis Ch. 4.3, Fig. 4.3, Table 4.1).

The CAE is pre-trained on synthetic wall layouts; its frozen encoder then turns an env's full
``m x n`` walls map into a ``1 x d`` embedding, one of the 9 reduced actor inputs and an input
of the centralised critic (section 4.5; ``ObservationSpec.walls_embedding``).

* Layouts: the walls the env itself draws at reset (``TargetLocalizationEnv.draw_walls`` on the
  env's layout stream), so the CAE sees exactly the training distribution of the policy. Chunk
  ``j`` of a data set of seed ``s`` equals the walls of ``TargetLocalizationEnv(spec,
  num_envs=chunk, seed=chunk_seed(s, j))`` after its first reset (rare layouts the env redraws
  because the target's pocket cannot hold the team are kept here).
* Model (ours: Fig. 4.3 is not described in the text): three 3x3 stride-2 convolutions
  (8, 16, 16 channels) -> fc -> tanh -> the d-vector (bounded like the normalised maps, line
  712); the decoder mirrors it with transposed convolutions and ends in per-cell logits
  (sigmoid + binary cross-entropy on the binary map). Table 4.1: Adam lr 1e-3, d = 128,
  100,000 layouts (our default is 20,000 so a 30 x 30 CAE trains in minutes on one core).
* Files: ``model.safetensors`` (``encoder.*`` and ``decoder.*``) + ``model.json`` (kind
  ``"cae"``, the env spec whose layouts it learned, grid, d, channels, training figures and
  held-out error against the all-empty and the mean-map baselines). ``load_cae(dir)`` rebuilds
  it from those two files only (no pickle), so a directory fetched by CID loads the same way.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.evaluate import chunk_seed
from workers.mdrl.spec import EnvSpec

KIND = "cae"
CHANNELS = (8, 16, 16)
"""Encoder conv channels (decoder: reversed)."""
DEFAULT_EMBEDDING = 128
"""d of Table 4.1."""
ARCHITECTURE = ("encoder: 3 x [conv3x3 stride 2 pad 1 -> ReLU] -> flatten -> fc d -> tanh; "
                "decoder: fc -> ReLU -> 3 x [transposed conv3x3 stride 2] (ReLU between) -> "
                "per-cell wall logits (sigmoid + BCE)")


# ----------------------------------------------------------------------------- layouts


def layout_stream(seed: int) -> np.random.Generator:
    """The env's layout generator for ``seed`` (``TargetLocalizationEnv.seed``: first spawn)."""
    layout, _noise = np.random.SeedSequence(seed).spawn(2)
    return np.random.Generator(np.random.PCG64(layout))


MAX_LAYOUT_CELLS = 1 << 29
"""Most cells of the layouts ``wall_layouts`` draws at once (512 MiB of bool; ~600,000 maps of
30 x 30, six times Table 4.1's): they are held in memory, and training copies them."""


def wall_layouts(spec: EnvSpec, count: int, seed: int = 0, chunk: int = 1000) -> np.ndarray:
    """bool (count, rows, cols): wall maps drawn as the env draws them (see module doc)."""
    if count < 1:
        raise ValueError(f"layout count must be >= 1, got {count}")
    if count * spec.num_cells > MAX_LAYOUT_CELLS:
        raise ValueError(f"{count:,} layouts of {spec.rows}x{spec.cols} are more than the "
                         f"{MAX_LAYOUT_CELLS // spec.num_cells:,} whose maps are held in memory "
                         f"({MAX_LAYOUT_CELLS:,} cells): draw fewer layouts")
    if spec.walls[1] == 0:
        raise ValueError(f"env spec has no walls (walls = {tuple(spec.walls)}): nothing to encode")
    out = np.empty((count, spec.rows, spec.cols), dtype=bool)
    for j, start in enumerate(range(0, count, chunk)):
        k = min(chunk, count - start)
        walls = TargetLocalizationEnv.draw_walls(spec, layout_stream(chunk_seed(seed, j)), k)
        out[start:start + k] = walls.reshape(k, spec.rows, spec.cols)
    return out


# ----------------------------------------------------------------------------- model


def _conv_sizes(size: int, layers: int) -> list[int]:
    """Spatial size after each stride-2 conv (kernel 3, pad 1): ceil(s / 2)."""
    sizes = [size]
    for _ in range(layers):
        sizes.append(math.ceil(sizes[-1] / 2))
    return sizes


class WallsEncoder(nn.Module):
    """walls (..., rows, cols) in {0, 1} -> embedding (..., d) in (-1, 1)."""

    def __init__(self, grid: tuple[int, int], embedding: int = DEFAULT_EMBEDDING,
                 channels: tuple[int, ...] = CHANNELS):
        super().__init__()
        rows, cols = (int(g) for g in grid)
        if min(rows, cols) < 2 or embedding < 1 or not channels or min(channels) < 1:
            raise ValueError(f"WallsEncoder needs a grid >= 2x2, d >= 1 and positive channels, "
                             f"got grid {grid}, d {embedding}, channels {channels}")
        self.grid, self.embedding, self.channels = (rows, cols), int(embedding), tuple(channels)
        layers: list[nn.Module] = []
        c_in = 1
        for c in channels:
            layers += [nn.Conv2d(c_in, c, 3, stride=2, padding=1), nn.ReLU()]
            c_in = c
        self.conv = nn.Sequential(*layers)
        h, w = _conv_sizes(rows, len(channels))[-1], _conv_sizes(cols, len(channels))[-1]
        self.code_shape = (c_in, h, w)
        self.fc = nn.Linear(c_in * h * w, self.embedding)

    def forward(self, walls: torch.Tensor) -> torch.Tensor:
        if tuple(walls.shape[-2:]) != self.grid:
            raise ValueError(f"walls encoder for a {self.grid[0]}x{self.grid[1]} grid got maps "
                             f"of shape {tuple(walls.shape)}")
        lead = walls.shape[:-2]
        x = walls.reshape(-1, 1, *self.grid).float()
        return torch.tanh(self.fc(self.conv(x).flatten(1))).reshape(*lead, self.embedding)


class WallsDecoder(nn.Module):
    """embedding (..., d) -> wall logits (..., rows, cols) (the encoder mirrored)."""

    def __init__(self, encoder: WallsEncoder):
        super().__init__()
        rows, cols = encoder.grid
        chans = encoder.channels
        self.grid, self.code_shape = encoder.grid, encoder.code_shape
        self.fc = nn.Linear(encoder.embedding, int(np.prod(encoder.code_shape)))
        hs, ws = _conv_sizes(rows, len(chans))[::-1], _conv_sizes(cols, len(chans))[::-1]
        outs = list(chans[::-1][1:]) + [1]
        layers: list[nn.Module] = []
        c_in = chans[-1]
        for i, c in enumerate(outs):
            # output size (s - 1) * 2 - 2 + 3 + pad = 2s - 1 + pad: pad picks the encoder's size
            pad = (hs[i + 1] - (2 * hs[i] - 1), ws[i + 1] - (2 * ws[i] - 1))
            layers.append(nn.ConvTranspose2d(c_in, c, 3, stride=2, padding=1,
                                             output_padding=pad))
            if i < len(outs) - 1:
                layers.append(nn.ReLU())
            c_in = c
        self.deconv = nn.Sequential(*layers)

    def forward(self, code: torch.Tensor) -> torch.Tensor:
        lead = code.shape[:-1]
        x = torch.relu(self.fc(code.reshape(-1, code.shape[-1]))).reshape(-1, *self.code_shape)
        return self.deconv(x).reshape(*lead, *self.grid)


class WallsCAE(nn.Module):
    """Encoder + decoder; ``forward`` gives per-cell wall logits of the reconstruction."""

    def __init__(self, grid: tuple[int, int], embedding: int = DEFAULT_EMBEDDING,
                 channels: tuple[int, ...] = CHANNELS):
        super().__init__()
        self.encoder = WallsEncoder(grid, embedding, channels)
        self.decoder = WallsDecoder(self.encoder)

    def forward(self, walls: torch.Tensor) -> torch.Tensor:
        return self.decoder(self.encoder(walls))


def parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


# ----------------------------------------------------------------------------- figures


def reconstruction_figures(prob: np.ndarray, walls: np.ndarray) -> dict[str, float]:
    """Held-out error of predicted wall probabilities ``prob`` against the true ``walls`` (both
    (n, rows, cols)): per-cell BCE, fraction of misclassified cells (threshold 0.5), IoU of wall
    cells (pooled over all maps) and the fraction of maps reconstructed without a wrong cell."""
    walls = walls.astype(bool)
    p = np.clip(prob.astype(np.float64), 1e-7, 1 - 1e-7)
    bce = float(-(walls * np.log(p) + (~walls) * np.log1p(-p)).mean())
    pred = prob >= 0.5
    wrong = pred != walls
    union = (pred | walls).sum()
    iou = float((pred & walls).sum() / union) if union else 1.0
    exact = float((~wrong.reshape(len(walls), -1).any(1)).mean())
    return {"bce": bce, "cell_error": float(wrong.mean()), "wall_iou": iou, "exact": exact}


def baseline_figures(train: np.ndarray, heldout: np.ndarray) -> dict[str, dict[str, float]]:
    """The trivial predictors: the all-empty map (its BCE is infinite: reported as None) and
    the per-cell wall frequency of the training layouts (the best input-blind predictor)."""
    empty = reconstruction_figures(np.full(heldout.shape, 1e-7), heldout)
    empty["bce"] = None  # log(0) on every wall cell
    mean_map = np.broadcast_to(train.mean(0), heldout.shape)
    return {"empty": empty, "mean_map": reconstruction_figures(mean_map, heldout)}


@torch.inference_mode()
def predict(model: WallsCAE, walls: np.ndarray, batch: int = 1024) -> np.ndarray:
    """Reconstructed wall probabilities (n, rows, cols) of maps ``walls``."""
    model.eval()
    out = [torch.sigmoid(model(torch.from_numpy(walls[i:i + batch]))).numpy()
           for i in range(0, len(walls), batch)]
    return np.concatenate(out)


# ----------------------------------------------------------------------------- training


class CAEDiverged(ValueError):
    """The loss or a weight went NaN/inf: nothing worth saving came out of the run."""


def _finite(module: nn.Module) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in module.state_dict().values())


def train_cae(spec: EnvSpec, layouts: int = 20_000, epochs: int = 20,
              embedding: int = DEFAULT_EMBEDDING, seed: int = 0, lr: float = 1e-3,
              batch: int = 128, heldout: float = 0.1, channels: tuple[int, ...] = CHANNELS,
              pos_weight: float = 1.0, progress: Callable[[int, float], None] | None = None
              ) -> tuple[WallsCAE, dict]:
    """Train a CAE on ``layouts`` env layouts; returns (model, card fields).

    A seeded ``heldout`` share of the layouts is never trained on and gives the figures
    (``reconstruction_figures``) next to the baselines; ``cae_unseen`` restricts them to the
    held-out maps that no training layout equals. ``progress(epoch, train_bce)`` is
    called after each epoch. ``pos_weight`` > 1 weighs wall cells up in the BCE. Seeds the
    data, the init and the minibatch order."""
    if not 0 < heldout < 1:
        raise ValueError(f"held-out share must be in (0, 1), got {heldout}")
    if epochs < 1 or batch < 1 or not (math.isfinite(lr) and lr > 0):
        raise ValueError(f"need epochs >= 1, batch >= 1, lr > 0; got {epochs}, {batch}, {lr}")
    if not (math.isfinite(pos_weight) and pos_weight > 0):
        raise ValueError(f"pos_weight (the BCE weight of wall cells) must be a finite number "
                         f"> 0, got {pos_weight}")
    data = wall_layouts(spec, layouts, seed)
    n_held = max(1, int(round(layouts * heldout)))
    if layouts - n_held < 1:
        raise ValueError(f"{layouts} layouts leave nothing to train on after the held-out split")
    order = np.random.default_rng([seed, 1]).permutation(layouts)
    train, held = data[order[n_held:]], data[order[:n_held]]
    gen = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        model = WallsCAE((spec.rows, spec.cols), embedding, channels)
    density = float(np.clip(train.mean(), 1e-4, 0.5))
    with torch.no_grad():  # start at the mean map's logit: the decoder learns the walls, not
        model.decoder.deconv[-1].bias.fill_(math.log(density / (1 - density)))  # the density
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    loss_fn = nn.BCEWithLogitsLoss(pos_weight=torch.tensor(float(pos_weight)))
    x_train = torch.from_numpy(train)
    history, t0 = [], time.perf_counter()
    for epoch in range(epochs):
        model.train()
        perm = torch.randperm(len(train), generator=gen)
        total = 0.0
        for i in range(0, len(train), batch):
            x = x_train[perm[i:i + batch]].float()
            loss = loss_fn(model(x), x)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += loss.item() * len(x)
        history.append(total / len(train))
        if not math.isfinite(history[-1]) or not _finite(model):
            raise CAEDiverged(f"CAE training diverged in epoch {epoch + 1} (train BCE "
                              f"{history[-1]}): lower the learning rate (now {lr:g})")
        if progress is not None:
            progress(epoch + 1, history[-1])
    wall_time = time.perf_counter() - t0
    # one-wall layouts are few (4 sides x places x lengths), so some held-out maps were also
    # drawn for training: report the CAE on the held-out maps it never saw, too
    train_keys = {row.tobytes() for row in np.packbits(train.reshape(len(train), -1), axis=1)}
    seen = np.array([r.tobytes() in train_keys
                     for r in np.packbits(held.reshape(len(held), -1), axis=1)])
    prob = predict(model, held)
    figures = {"cae": reconstruction_figures(prob, held)}
    if not seen.all():
        figures["cae_unseen"] = reconstruction_figures(prob[~seen], held[~seen])
    figures.update(baseline_figures(train, held))
    info = {
        "training": {"layouts": layouts, "train_layouts": len(train), "heldout_layouts": n_held,
                     "epochs": epochs, "batch": batch, "learning_rate": lr, "optimizer": "Adam",
                     "loss": "per-cell binary cross-entropy", "seed": seed,
                     "train_bce": history, "wall_time_s": wall_time,
                     "heldout_also_in_train": float(seen.mean()),
                     "wall_density": float(train.mean())},
        "heldout": figures,
    }
    return model, info


# ----------------------------------------------------------------------------- files

FORMAT = "drlaas-model/1"
WEIGHTS, CARD = "model.safetensors", "model.json"


def tensor_digest(tensors: dict[str, torch.Tensor]) -> str:
    """sha256 over names, dtypes, shapes and bytes of ``tensors`` (independent of the file
    layout, so an encoder copied into a policy's file keeps its digest)."""
    h = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].detach().contiguous().cpu()
        h.update(f"{name}|{t.dtype}|{list(t.shape)}|".encode())
        h.update(t.numpy().tobytes())
    return "sha256:" + h.hexdigest()


def encoder_card(encoder: WallsEncoder) -> dict[str, Any]:
    """What rebuilds an encoder: grid, d, channels, and the digest of its weights."""
    return {"kind": KIND, "grid": list(encoder.grid), "embedding": encoder.embedding,
            "channels": list(encoder.channels),
            "digest": tensor_digest(encoder.state_dict())}


def save_cae(path: str | Path, model: WallsCAE, spec: EnvSpec,
             info: dict[str, Any] | None = None) -> Path:
    """Write ``model.safetensors`` + ``model.json`` (kind ``"cae"``) into directory ``path``."""
    from workers.mdrl.modelio import code_version

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().contiguous().clone() for k, v in model.state_dict().items()}
    save_file(tensors, str(path / WEIGHTS), metadata={"format": FORMAT, "kind": KIND})
    enc = model.encoder
    card = {
        "format": FORMAT, "kind": KIND,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "env": spec.to_dict(),
        "grid": list(enc.grid), "embedding": enc.embedding,
        "architecture": {"description": ARCHITECTURE, "channels": list(enc.channels),
                         "code_shape": list(enc.code_shape),
                         "encoder_parameters": parameters(enc),
                         "decoder_parameters": parameters(model.decoder)},
        "encoder_digest": tensor_digest(enc.state_dict()),
        **(info or {}),
        "code": code_version(),
    }
    (path / CARD).write_text(json.dumps(card, indent=1))
    return path


def load_cae_card(path: str | Path) -> dict[str, Any]:
    """``model.json`` of a CAE directory, checked to be a CAE card."""
    card_path = Path(path) / CARD
    if not card_path.is_file():
        raise FileNotFoundError(f"not a CAE directory {path}: no {CARD}")
    card = json.loads(card_path.read_text())
    if not isinstance(card, dict):
        raise ValueError(f"{card_path}: a card is a JSON object, got {type(card).__name__}")
    if card.get("format") != FORMAT or card.get("kind") != KIND:
        raise ValueError(f"{card_path}: not a walls CAE card (format {card.get('format')!r}, "
                         f"kind {card.get('kind')!r}; want {FORMAT!r}, kind {KIND!r})")
    return card


MAX_CAE_GRID, MAX_CAE_EMBEDDING, MAX_CAE_LAYERS, MAX_CAE_CHANNELS = 1024, 1024, 8, 1024


def check_cae_fields(card: dict[str, Any]) -> None:
    """ValueError unless ``card`` has the fields an encoder is rebuilt (and sized) from, in
    bounds: grid (two ints), embedding d and architecture.channels (a worker's check and the
    gateway's, before anything is allocated from them)."""
    try:
        grid, d = card["grid"], card["embedding"]
        channels = card["architecture"]["channels"]
    except (KeyError, TypeError) as exc:
        raise ValueError(f"no grid, embedding or architecture.channels ({exc})") from None
    def whole(v: Any, lo: int, hi: int) -> bool:  # JSON true is not a 1
        return isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi

    ok = (
        isinstance(grid, list)
        and len(grid) == 2
        and all(whole(g, 2, MAX_CAE_GRID) for g in grid)
        and whole(d, 1, MAX_CAE_EMBEDDING)
        and isinstance(channels, list)
        and 1 <= len(channels) <= MAX_CAE_LAYERS
        and all(whole(c, 1, MAX_CAE_CHANNELS) for c in channels)
    )
    if not ok:
        raise ValueError("grid, embedding or architecture.channels out of range")


def check_encoder_fields(info: dict[str, Any]) -> None:
    """``check_cae_fields`` for a policy card's ``walls_encoder`` (``encoder_card``: grid,
    embedding and channels at its top level)."""
    check_cae_fields({"grid": info.get("grid"), "embedding": info.get("embedding"),
                      "architecture": {"channels": info.get("channels")}})


def load_cae(path: str | Path) -> WallsCAE:
    """Rebuild a CAE from its directory (safetensors + JSON card only; never unpickles).
    A damaged directory (card fields missing or of the wrong type, weights truncated, of other
    shapes, not finite or not the card's digest) is a ValueError naming it."""
    card = load_cae_card(path)
    weights = Path(path) / WEIGHTS
    if not weights.is_file():
        raise FileNotFoundError(f"CAE directory {path} has no {WEIGHTS}")
    try:
        tensors = load_file(str(weights))
        model = _build_for(WallsCAE, tensors, _grid_field(card["grid"]), int(card["embedding"]),
                           tuple(card["architecture"]["channels"]))
        model.load_state_dict(tensors)
        digest = card["encoder_digest"]
    except (KeyError, TypeError, ValueError, RuntimeError, SafetensorError) as exc:
        raise ValueError(f"{path} is not a usable walls CAE: {error_text(exc)}") from None
    if tensor_digest(model.encoder.state_dict()) != digest:
        raise ValueError(f"{weights}: encoder weights do not match the card's digest")
    if not _finite(model):
        raise ValueError(f"{weights}: the CAE holds NaN or infinite weights (a diverged run)")
    model.eval()
    return model


def encoder_from_tensors(card: dict[str, Any], tensors: dict[str, torch.Tensor]) -> WallsEncoder:
    """Rebuild an encoder from ``encoder_card`` fields and its state dict (digest checked)."""
    if not isinstance(card, dict):
        raise ValueError(f"the card's walls_encoder must be an object, got {type(card).__name__}")
    if card.get("kind") != KIND:
        raise ValueError(f"walls encoder card has kind {card.get('kind')!r}, want {KIND!r}")
    if all(k in card for k in ("grid", "embedding", "channels")):  # else named below
        try:  # bounded first: building the layout costs a layer per listed channel
            check_encoder_fields(card)
        except ValueError as exc:
            raise ValueError(f"the card's walls_encoder is unusable: {exc}") from None
    try:
        enc = _build_for(WallsEncoder, tensors, _grid_field(card["grid"]),
                         int(card["embedding"]), tuple(card["channels"]))
        enc.load_state_dict(tensors)
        digest = card["digest"]
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(f"the card's walls_encoder is unusable: {error_text(exc)}") from None
    if tensor_digest(enc.state_dict()) != digest:
        raise ValueError("walls encoder weights do not match the digest recorded in the card")
    if not _finite(enc):
        raise ValueError("the walls encoder holds NaN or infinite weights")
    return enc.eval()


def _build_for(kind: type[nn.Module], tensors: dict[str, torch.Tensor], *args: Any) -> Any:
    """``kind(*args)`` once its parameter shapes (laid out on the meta device, which allocates
    nothing) are the shapes of ``tensors``: a card's grid, d and channels come from the network,
    and a few numbers can ask for gigabytes (a 79 kB card made the worker allocate 1.9 GB)
    while the weights, bounded by the file's size, cannot."""
    with torch.device("meta"):
        layout = kind(*args)
    want = {k: tuple(v.shape) for k, v in layout.state_dict().items()}
    have = {k: tuple(v.shape) for k, v in tensors.items()}
    if want != have:
        wrong = sorted(k for k in want.keys() | have.keys() if want.get(k) != have.get(k))
        raise ValueError(f"the card's grid, embedding and channels ask for tensors the weights "
                         f"do not hold ({', '.join(wrong[:4])}"
                         f"{', ...' if len(wrong) > 4 else ''})")
    return kind(*args)


def _grid_field(value: Any) -> tuple[int, int]:
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
        raise ValueError(f"grid must be [rows, cols], got {value!r}")
    return value[0], value[1]


def error_text(exc: BaseException) -> str:
    """One line for a card or weights error (a KeyError names the missing field); also what
    ``Trainer.load_state`` says of checkpoint weights that do not fit."""
    if isinstance(exc, KeyError):
        return f"the card has no {exc}"
    # torch's load_state_dict says what it is about on the first line, what is wrong on the next
    text = " ".join(line.strip() for line in str(exc).splitlines()[:2])
    return text[:300] or type(exc).__name__


# ----------------------------------------------------------------------------- observations


class WallsEmbedder:
    """The frozen encoder as an observation builder: (B, C) walls -> (B, d) float32.

    Walls are fixed within an episode, so embeddings are cached per env row and recomputed
    only for rows whose walls map changed since the last call (a new episode's layout). The
    cache compares map contents, so it stays right for any batch (row views, resets,
    restored checkpoints)."""

    def __init__(self, encoder: WallsEncoder, source: str | None = None):
        self.encoder = encoder.eval()
        for p in self.encoder.parameters():
            p.requires_grad_(False)
        self.source = source
        self.grid, self.size = encoder.grid, encoder.embedding
        self.card = {**encoder_card(encoder), "source": source}
        self._walls: np.ndarray | None = None
        self._codes: np.ndarray | None = None
        self.encoded = 0  # maps run through the encoder (the cache's work)

    @classmethod
    def load(cls, path: str | Path) -> WallsEmbedder:
        """The encoder of the CAE directory ``path``."""
        return cls(load_cae(path).encoder, str(path))

    def embed(self, walls: np.ndarray) -> np.ndarray:
        walls = np.asarray(walls, dtype=bool)
        cells = self.grid[0] * self.grid[1]
        if walls.ndim != 2 or walls.shape[1] != cells:
            raise ValueError(f"walls embedding for a {self.grid[0]}x{self.grid[1]} grid needs "
                             f"walls of shape (B, {cells}), got {walls.shape}")
        if self._walls is None or self._walls.shape != walls.shape:
            self._walls = walls.copy()
            self._codes = np.empty((len(walls), self.size), np.float32)
            stale = np.arange(len(walls))
        else:
            stale = np.flatnonzero((self._walls != walls).any(1))
            self._walls[stale] = walls[stale]
        if len(stale):
            with torch.inference_mode():
                maps = torch.from_numpy(walls[stale].reshape(-1, *self.grid))
                self._codes[stale] = self.encoder(maps).numpy()
            self.encoded += len(stale)
        return self._codes.copy()
