"""Measured capabilities of this machine, as the UMC records them (thesis Table 7.2)."""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path

#: GPU series code for "no GPU" (the TMC's accepted-GPU mask excludes it by default).
NO_GPU = 0


@dataclass(frozen=True)
class Capabilities:
    cpu_cores: int
    ram_gb: int
    gpu_series: int

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


def ram_gb(meminfo: str | Path = "/proc/meminfo") -> int:
    """Total RAM in whole GiB from ``/proc/meminfo`` (``MemTotal: N kB``), at least 1."""
    return max(1, ram_bytes(meminfo) // 2**30)


def ram_bytes(meminfo: str | Path = "/proc/meminfo") -> int:
    """Total RAM in bytes from ``/proc/meminfo`` (``MemTotal: N kB``): what a worker's jobs
    may use together (the offer handler splits it over its concurrent jobs)."""
    text = Path(meminfo).read_text()
    for line in text.splitlines():
        if line.startswith("MemTotal:"):
            parts = line.split()
            kib = int(parts[1])
            unit = parts[2].lower() if len(parts) > 2 else "kb"
            if unit != "kb":
                raise ValueError(f"{meminfo}: unexpected MemTotal unit {parts[2]!r}")
            return kib * 1024
    raise ValueError(f"{meminfo}: no MemTotal line")


def gpu_series() -> int:
    """0 without CUDA; otherwise the compute-capability major version as a series code
    (1-255), which is how the TMC's accepted-GPU mask is keyed here."""
    try:
        import torch

        if not torch.cuda.is_available():
            return NO_GPU
        major, _minor = torch.cuda.get_device_capability(0)
        return max(1, min(255, int(major)))
    except Exception:  # noqa: BLE001 - a broken CUDA install means "no usable GPU"
        return NO_GPU


def measure() -> Capabilities:
    """CPU cores (os.cpu_count), RAM (GiB, /proc/meminfo) and GPU series of this machine."""
    return Capabilities(cpu_cores=os.cpu_count() or 1, ram_gb=ram_gb(), gpu_series=gpu_series())
