"""Random-number state: seeding a run, and the snapshot a checkpoint holds so that a resumed run
draws exactly what an uninterrupted one would (torch CPU and CUDA, the run's generator, Python, NumPy)."""

from __future__ import annotations

import random
from contextlib import contextmanager

import numpy as np
import torch


def seed_everything(seed: int) -> torch.Generator:
    """Seed Python, NumPy and torch; a fresh torch.Generator seeded the same (initialisation draws from it)."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return torch.Generator().manual_seed(seed)


def keyed_generator(seed: int, *key: int) -> torch.Generator:
    """A CPU torch.Generator that is a pure function of (seed, key...) (NumPy's SeedSequence mixes
    them, so distinct keys never collide): draws that must repeat exactly in a resumed run, such as
    an epoch's view order or a step's dropped Gaussians, take one of these instead of run state."""
    state = np.random.SeedSequence([seed % 2**64, *(int(k) for k in key)]).generate_state(1, dtype=np.uint64)[0]
    return torch.Generator().manual_seed(int(state) % 2**63)


@contextmanager
def rng_untouched():
    """A block that leaves torch's global random state as it found it (CPU and every CUDA device).

    Matching runs in one: building a learned matcher initialises its modules at random before
    loading the weights, so without it a run whose matches were computed trained differently
    from the same run reading them from the cache (lego, 3 views, seed 0: 16.79 against 16.60)."""
    devices = list(range(torch.cuda.device_count())) if torch.cuda.is_available() else []
    with torch.random.fork_rng(devices=devices):
        yield


def rng_state(generator: torch.Generator, device: torch.device) -> dict:
    """Every random state a run draws from, as checkpoint entries (tensors and plain values only)."""
    return {
        "torch_rng": torch.get_rng_state(),
        "cuda_rng": torch.cuda.get_rng_state_all() if device.type == "cuda" else [],
        "generator_rng": generator.get_state(),
        "python_rng": random.getstate(),
        "numpy_rng": _numpy_state_to_payload(),
    }


def restore_rng_state(payload: dict, generator: torch.Generator, device: torch.device) -> None:
    """Set the states :func:`rng_state` saved (the Python and NumPy entries are optional: older checkpoints)."""
    torch.set_rng_state(payload["torch_rng"])
    if payload.get("cuda_rng") and device.type == "cuda":
        torch.cuda.set_rng_state_all(payload["cuda_rng"])
    generator.set_state(payload["generator_rng"])
    if "python_rng" in payload:
        random.setstate(payload["python_rng"])
    if "numpy_rng" in payload:
        _numpy_state_from_payload(payload["numpy_rng"])


def _numpy_state_to_payload() -> dict:
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
            "has_gauss": int(has_gauss), "cached": float(cached)}


def _numpy_state_from_payload(s: dict) -> None:
    keys = s["keys"].numpy().astype(np.uint32)
    np.random.set_state((s["name"], keys, s["pos"], s["has_gauss"], s["cached"]))
