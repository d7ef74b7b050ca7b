"""What a target-localization environment is: pure data that round-trips through JSON.

The thesis fixes the Ch. 3 set-up (1 km x 1 km, 10 x 10, I = 1e9, 4 moves + idle) and the
Ch. 4 options (8 moves, walls from the sides); everything else is ours and documented here.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: (drow, dcol) per action; index 0 is IDLE. 4-move: up, down, left, right.
MOVES_4 = np.array([(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)], dtype=np.int64)
#: 8-move, Eq. 7 (theta = 2 pi b / 8, b = 1..8, counter-clockwise from east; row axis points down).
MOVES_8 = np.array(
    [(0, 0)]
    + [
        (-int(round(math.sin(2 * math.pi * b / 8))), int(round(math.cos(2 * math.pi * b / 8))))
        for b in range(8)
    ],
    dtype=np.int64,
)
MOVES = {4: MOVES_4, 8: MOVES_8}
#: Most cells (rows * cols) of a grid. The env and observers build dense cells x cells tables
#: (distances, path gains, the belief filter): 64 x 64 = 4,096 cells is ~128 MiB per float64
#: table, 120 x 120 already runs out of memory. The task spec's grid (trainingspec.MAX_GRID
#: per side) stays within it; a long thin grid (6 x 70) is fine.
MAX_CELLS = 64 * 64
#: Largest expected reading (counts) an env may draw: numpy's Poisson sampler refuses means
#: above ~9.2e18, and float32 reading maps lose all meaning long before float64 overflows.
MAX_EXPECTED_COUNT = 1e18
ACTION_NAMES = {
    4: ("idle", "up", "down", "left", "right"),
    8: ("idle", "E", "NE", "N", "NW", "W", "SW", "S", "SE"),
}


MAX_STEP_COUNT = 2**31 - 1
"""Largest max_steps / idle_limit: the env's kernels count steps in int64 and compare them."""
MAX_AREA_M = 1e7
# Eq. 9's success bonus S (the thesis: 50); a bound keeps the returns finite in float32.
MAX_SPARSE_BONUS = 1e6
"""Largest side of the search area (10,000 km): 1e300 m overflowed Eq. 6's distances."""

@dataclass(frozen=True)
class IntensitySpec:
    """Source intensity in photons/min: one value, a set to draw from, or a uniform range."""

    kind: str = "fixed"  # "fixed" | "choice" | "uniform"
    values: tuple[float, ...] = (1e9,)

    def __post_init__(self) -> None:
        if not isinstance(self.values, tuple) or not all(
                isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                for v in self.values):
            raise ValueError(f"intensity values must be a tuple of numbers, got {self.values!r}")
        if self.kind not in ("fixed", "choice", "uniform"):
            raise ValueError(f"intensity kind must be fixed, choice or uniform, got {self.kind!r}")
        if not self.values or any(not (v > 0 and math.isfinite(v)) for v in self.values):
            raise ValueError(f"intensity values must be positive and finite, got {self.values}")
        if self.kind == "fixed" and len(self.values) != 1:
            raise ValueError("a fixed intensity has exactly one value")
        if self.kind == "uniform" and (len(self.values) != 2 or self.values[0] > self.values[1]):
            raise ValueError(
                f"a uniform intensity needs (low, high) with low <= high, got {self.values}"
            )

    @classmethod
    def fixed(cls, value: float) -> IntensitySpec:
        return cls("fixed", (float(value),))

    @classmethod
    def choice(cls, values: tuple[float, ...] | list[float]) -> IntensitySpec:
        return cls("choice", tuple(float(v) for v in values))

    @classmethod
    def uniform(cls, low: float, high: float) -> IntensitySpec:
        return cls("uniform", (float(low), float(high)))

    @classmethod
    def parse(cls, text: str) -> IntensitySpec:
        """'1e9' -> fixed, '1e8,5e8,1e9' -> choice, '1e8:1e9' -> uniform."""
        text = text.strip()
        try:
            if ":" in text:
                low, high = text.split(":")
                return cls.uniform(float(low), float(high))
            if "," in text:
                return cls.choice([float(v) for v in text.split(",")])
            return cls.fixed(float(text))
        except ValueError as exc:
            raise ValueError(
                f"intensity {text!r}: expected 1e9, a set 1e8,5e8,1e9 or a range 1e8:1e9 ({exc})"
            ) from None

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        if self.kind == "fixed":
            return np.full(size, self.values[0])
        if self.kind == "choice":
            return rng.choice(np.asarray(self.values), size=size)
        return rng.uniform(self.values[0], self.values[1], size=size)

    def __str__(self) -> str:
        sep = {"fixed": "", "choice": ",", "uniform": ":"}[self.kind]
        return sep.join(f"{v:g}" for v in self.values)


@dataclass(frozen=True)
class EnvSpec:
    """A target-localization environment (thesis Ch. 3.2, 3.7.1, 4.3-4.4).

    Reading model (Eq. 6, ours where the thesis is silent): the expected count of a detector of
    area ``detector_area_cm2`` dwelling ``dwell_min`` minutes at distance d from an isotropic source
    of I photons/min is ``I * dwell * area / (4 pi d^2)``, times the Beer-Lambert transmission
    ``exp(-mu * t / cos(theta))`` of every wall the straight source-detector line crosses (walls
    are thin slabs of thickness ``wall_thickness_cm`` on the centre line of their cells; theta is
    the angle to the wall's normal). d is floored at half a cell side, so the reading on the target
    cell is finite. A reading is a Poisson draw with that mean (``readings="poisson"``), or the
    mean itself (``readings="expected"``, what the thesis author's public code does).
    """

    rows: int = 10
    cols: int = 10
    area_m: tuple[float, float] = (1000.0, 1000.0)
    agents: int = 3
    intensity: IntensitySpec = field(default_factory=lambda: IntensitySpec.fixed(1e9))
    moves: int = 4
    walls: tuple[int, int] = (0, 0)
    wall_length: tuple[int, int] | None = None
    reward: str = "shaped"
    sparse_bonus: float = 50.0
    max_steps: int = 100
    idle_limit: int = 3
    detector_area_cm2: float = 200.0
    dwell_min: float = 1.0
    wall_mu_per_cm: float = 0.178
    wall_thickness_cm: float = 10.0
    readings: str = "poisson"

    def __post_init__(self) -> None:
        _check_types(self)
        problems = []
        if self.rows < 2 or self.cols < 2:
            problems.append(f"grid (rows x cols) must be at least 2x2, got "
                            f"{self.rows}x{self.cols}")
        elif self.rows * self.cols > MAX_CELLS:
            problems.append(f"grid (rows x cols) {self.rows}x{self.cols} has "
                            f"{self.rows * self.cols:,} cells, more than {MAX_CELLS:,} (64x64): "
                            f"the env keeps cells x cells tables")
        if self.agents < 1:
            problems.append(f"agents must be >= 1, got {self.agents}")
        if self.agents + 1 > self.rows * self.cols:
            problems.append(
                f"{self.agents} agents and a target do not fit on {self.rows}x{self.cols}"
            )
        if self.moves not in MOVES:
            problems.append(f"moves must be 4 or 8, got {self.moves}")
        lo, hi = self.walls
        if not 0 <= lo <= hi:
            problems.append(f"walls must be (min, max) with 0 <= min <= max, got {self.walls}")
        if self.wall_length is not None:
            wl, wh = self.wall_length
            if not 1 <= wl <= wh:
                problems.append(
                    f"wall_length must be (min, max) with 1 <= min <= max, got {self.wall_length}"
                )
        if hi > 0 and min(self.rows, self.cols) < 4:
            problems.append("walls need a grid of at least 4x4")
        elif hi > 0 and hi > 2 * (self.rows - 2) + 2 * (self.cols - 2):
            problems.append(
                f"at most {2 * (self.rows - 2) + 2 * (self.cols - 2)} walls fit on "
                f"{self.rows}x{self.cols} (one per non-corner side cell), got {hi}"
            )
        if self.reward not in ("shaped", "sparse"):
            problems.append(
                f"reward must be 'shaped' (Eq. 5/8) or 'sparse' (Eq. 9), got {self.reward!r}"
            )
        if self.readings not in ("poisson", "expected"):
            problems.append(f"readings must be 'poisson' or 'expected', got {self.readings!r}")
        if not 1 <= self.max_steps <= MAX_STEP_COUNT:
            problems.append(f"max_steps must be in 1..{MAX_STEP_COUNT}, got {self.max_steps}")
        if not 1 <= self.idle_limit <= MAX_STEP_COUNT:  # int64 kernels: 1e30 overflowed numba
            problems.append(f"idle_limit must be in 1..{MAX_STEP_COUNT}, got {self.idle_limit}")
        if min(self.area_m) <= 0 or max(self.area_m) > MAX_AREA_M:
            problems.append(f"area_m must be in (0, {MAX_AREA_M:g}] m, got {self.area_m}")
        elif self.rows >= 2 and self.cols >= 2 and self.detector_area_cm2 > 0 and \
                self.dwell_min > 0 and self.peak_expected_count > MAX_EXPECTED_COUNT:
            problems.append(
                f"intensity up to {max(self.intensity.values):g} photons/min gives an expected "
                f"reading of {self.peak_expected_count:.3g} counts next to the source "
                f"(dwell_min {self.dwell_min:g}, detector_area_cm2 {self.detector_area_cm2:g}, "
                f"cells of {min(self.cell_size_m):g} m), more than the readings can take "
                f"({MAX_EXPECTED_COUNT:g}): lower the intensity")
        if not 0 <= self.sparse_bonus <= MAX_SPARSE_BONUS:
            problems.append(f"sparse_bonus (Eq. 9's S) must be in 0..{MAX_SPARSE_BONUS:g}, "
                            f"got {self.sparse_bonus:g}")
        for name in ("detector_area_cm2", "dwell_min"):
            if getattr(self, name) <= 0:
                problems.append(f"{name} must be positive")
        for name in ("wall_mu_per_cm", "wall_thickness_cm"):
            if getattr(self, name) < 0:
                problems.append(f"{name} must be non-negative, got {getattr(self, name)}")
        if problems:
            raise ValueError("; ".join(problems))

    @property
    def peak_expected_count(self) -> float:
        """The largest mean reading of Eq. 6 this env can produce: the largest intensity at
        the floored distance of half a cell side, no wall in between."""
        d_cm = min(self.cell_size_m) * 100 / 2
        return (max(self.intensity.values) * self.dwell_min * self.detector_area_cm2
                / (4 * math.pi * d_cm**2))

    @property
    def num_actions(self) -> int:
        return self.moves + 1

    @property
    def num_cells(self) -> int:
        return self.rows * self.cols

    @property
    def cell_size_m(self) -> tuple[float, float]:
        return self.area_m[0] / self.rows, self.area_m[1] / self.cols

    def wall_length_range(self, span: int) -> tuple[int, int]:
        """Wall lengths for a side of ``span`` cells: at most span - 2, never sealing a side."""
        lo, hi = self.wall_length if self.wall_length is not None else (2, span - 2)
        hi = min(hi, span - 2)
        return min(lo, hi), hi

    def replace(self, **changes: Any) -> EnvSpec:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["intensity"] = {"kind": self.intensity.kind, "values": list(self.intensity.values)}
        d["area_m"] = list(self.area_m)
        d["walls"] = list(self.walls)
        d["wall_length"] = list(self.wall_length) if self.wall_length is not None else None
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EnvSpec:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown environment fields: {sorted(unknown)}")
        d = dict(d)
        if "intensity" in d and not isinstance(d["intensity"], IntensitySpec):
            d["intensity"] = _intensity_from(d["intensity"])
        for key in ("area_m", "walls", "wall_length"):
            if isinstance(d.get(key), list):  # anything else: _check_types names the field
                d[key] = tuple(d[key])
        return cls(**d)


def _intensity_from(it: Any) -> IntensitySpec:
    """An IntensitySpec from a config value: a number, a string ('1e9', '1e8,1e9',
    '1e8:1e9') or {"kind": ..., "values": [...]}; ValueError naming the field otherwise."""
    what = ("a number (1e9), a string ('1e8,5e8,1e9' or '1e8:1e9') or "
            "{\"kind\": fixed|choice|uniform, \"values\": [numbers]}")
    if isinstance(it, (int, float)) and not isinstance(it, bool):
        return IntensitySpec.fixed(it)
    if isinstance(it, str):
        return IntensitySpec.parse(it)
    if not isinstance(it, dict):
        raise ValueError(f"environment field intensity must be {what}, got {it!r}")
    unknown = sorted(set(it) - {"kind", "values"})
    values = it.get("values")
    if unknown or not isinstance(values, (list, tuple)) or not isinstance(
            it.get("kind", "fixed"), str) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        raise ValueError(f"environment field intensity must be {what}, got {it!r}")
    return IntensitySpec(it.get("kind", "fixed"), tuple(float(v) for v in values))


_INT_FIELDS = ("rows", "cols", "agents", "moves", "max_steps", "idle_limit")
_REAL_FIELDS = ("sparse_bonus", "detector_area_cm2", "dwell_min", "wall_mu_per_cm",
                "wall_thickness_cm")
_PAIR_FIELDS = {"area_m": (int, float, np.integer, np.floating), "walls": (int, np.integer),
                "wall_length": (int, np.integer)}


def _check_types(spec: EnvSpec) -> None:
    """ValueError naming the field when a config or card gives a value of the wrong type
    (``rows = "x"``), before a comparison fails with a TypeError that names nothing."""

    def bad(name: str, want: str) -> ValueError:
        return ValueError(f"environment field {name} must be {want}, got "
                         f"{getattr(spec, name)!r}")

    for name in _INT_FIELDS:
        v = getattr(spec, name)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise bad(name, "an integer")
    for name in _REAL_FIELDS:
        v = getattr(spec, name)
        number = isinstance(v, (int, float, np.number)) and not isinstance(v, bool)
        if not number or not math.isfinite(v):
            raise bad(name, "a finite number")
    for name, kinds in _PAIR_FIELDS.items():
        v = getattr(spec, name)
        if v is None and name == "wall_length":
            continue
        if not (isinstance(v, tuple) and len(v) == 2 and all(
                isinstance(x, kinds) and not isinstance(x, bool) for x in v)):
            raise bad(name, "a pair of " + ("numbers" if name == "area_m" else "integers"))
        if name == "area_m" and not all(math.isfinite(x) for x in v):
            raise bad(name, "a pair of finite numbers")
    for name in ("reward", "readings"):
        if not isinstance(getattr(spec, name), str):
            raise bad(name, "a string")
    if not isinstance(spec.intensity, IntensitySpec):
        raise bad("intensity", "an IntensitySpec")


def parse_grid(text: str) -> tuple[int, int]:
    """'10x10' -> (10, 10)."""
    try:
        rows, cols = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"grid {text!r}: expected ROWSxCOLS, e.g. 10x10") from None
    return rows, cols


def parse_walls(text: str) -> tuple[int, int]:
    """'2' -> (2, 2), '0-3' -> (0, 3)."""
    try:
        if "-" in text:
            lo, hi = (int(v) for v in text.split("-"))
        else:
            lo = hi = int(text)
    except ValueError:
        raise ValueError(f"walls {text!r}: expected a count (2) or a range (0-3)") from None
    return lo, hi
