"""``MatchSet``: the verified matches of every pair of views, and its on-disk format."""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..runtime.io import atomic_write_bytes

#: Bump when the matching pipeline changes in a way that invalidates caches.
CACHE_VERSION = 5


Pair = tuple[int, int]


@dataclass
class MatchSet:
    """Verified matches for every pair (i, j), i < j, of the given views.

    Attributes:
        view_ids: the views (dataset indices), ascending.
        matches: (i, j) -> (pixels in view i [M, 2] float32, pixels in view j [M, 2] float32),
            continuous coordinates (pixel centres at +0.5).
        image_sizes: view id -> (width, height) of the matched images.
        warnings: (i, j) -> why that pair ended empty (too few matches).
        stats: (i, j) -> counts at each stage ("raw", "magsac", "epipolar", "final").
        meta: free-form info (config, cache key, seconds).
    """

    view_ids: list[int]
    matches: dict[Pair, tuple[np.ndarray, np.ndarray]]
    image_sizes: dict[int, tuple[int, int]] = field(default_factory=dict)
    warnings: dict[Pair, str] = field(default_factory=dict)
    stats: dict[Pair, dict[str, int]] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def pairs(self) -> list[Pair]:
        """All pairs (i, j), i < j, in ascending order (empty pairs included)."""
        return sorted(self.matches)

    def get(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """(pixels in view i, pixels in view j); works for either order of i and j."""
        if (i, j) in self.matches:
            return self.matches[(i, j)]
        a, b = self.matches[(j, i)]
        return b, a

    def count(self, i: int, j: int) -> int:
        return len(self.get(i, j)[0])

    def digest(self) -> str:
        """16 hex digits of a sha1 over the views and every pair's matched pixels, bit for bit: the
        same matches give the same digest on any machine. A run whose model starts from matches
        records it (``init_stats["matches_digest"]`` in metrics.json), because matching's sums, and so a few of
        its matches, follow the thread count and the processor, and a run on other matches follows
        another path (a seed's PSNR moved by up to 0.2 dB, docs/results.md): two runs' numbers differ
        by their code or by their matches, and the digest tells which."""
        h = hashlib.sha1(json.dumps([int(v) for v in self.view_ids]).encode())
        for pair in self.pairs():
            h.update(f"{int(pair[0])},{int(pair[1])}".encode())  # numpy or Python ints alike
            for pts in self.matches[pair]:
                h.update(np.ascontiguousarray(pts, np.float32).tobytes())
        return h.hexdigest()[:16]

    def total(self) -> int:
        """Number of matches over all pairs."""
        return int(sum(len(a) for a, _ in self.matches.values()))

    def summary(self) -> dict[Pair, int]:
        """Matches per pair."""
        return {p: len(self.matches[p][0]) for p in self.pairs()}

    def unmatched_views(self) -> list[int]:
        """The views (of two or more) without one verified match with any other view."""
        if len(self.view_ids) < 2:
            return []
        matched = {v for (i, j), (a, _) in self.matches.items() if len(a) for v in (i, j)}
        return [v for v in self.view_ids if v not in matched]

    @property
    def n_warnings(self) -> int:
        return len(self.warnings)

    def concatenated(self) -> dict[str, np.ndarray]:
        """All matches flattened: view_a, view_b [N] int64, pix_a, pix_b [N, 2] float32."""
        ps = self.pairs()
        n = [len(self.matches[p][0]) for p in ps]
        return {
            "view_a": np.repeat(np.array([p[0] for p in ps], np.int64), n),
            "view_b": np.repeat(np.array([p[1] for p in ps], np.int64), n),
            "pix_a": np.concatenate([self.matches[p][0] for p in ps] or [np.zeros((0, 2))]).astype(np.float32),
            "pix_b": np.concatenate([self.matches[p][1] for p in ps] or [np.zeros((0, 2))]).astype(np.float32),
        }

    # ----------------------------------------------------------------- io
    def save(self, path: Path | str) -> Path:
        """Write an .npz atomically (:func:`splat_framework.runtime.io.atomic_write_bytes`: a temp file in the same folder, fsync, rename)."""
        path = Path(path)
        ps = self.pairs()
        flat = self.concatenated()
        meta = {
            "format": "scg-matchset",
            "version": CACHE_VERSION,
            "warnings": [[i, j, w] for (i, j), w in sorted(self.warnings.items())],
            "stats": [[i, j, s] for (i, j), s in sorted(self.stats.items())],
            "meta": self.meta,
        }
        sizes = np.array([[v, *self.image_sizes.get(v, (-1, -1))] for v in self.view_ids], np.int64).reshape(-1, 3)
        arrays = {
            "view_ids": np.asarray(self.view_ids, np.int64),
            "image_sizes": sizes,
            "pairs": np.asarray(ps, np.int64).reshape(-1, 2),
            "counts": np.asarray([len(self.matches[p][0]) for p in ps], np.int64),
            "pix_a": flat["pix_a"],
            "pix_b": flat["pix_b"],
            "meta": np.asarray(json.dumps(meta, default=str)),
        }
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())
        return path

    @classmethod
    def load(cls, path: Path | str) -> "MatchSet":
        """Read a file written by :meth:`save`; ValueError if it is not a valid match set."""
        with np.load(Path(path), allow_pickle=False) as z:
            try:
                meta = json.loads(str(z["meta"]))
                view_ids = [int(v) for v in z["view_ids"]]
                sizes = z["image_sizes"]
                pairs = z["pairs"]
                counts = z["counts"]
                pix_a, pix_b = z["pix_a"], z["pix_b"]
            except KeyError as e:
                raise ValueError(f"{path}: not a match set (missing {e})") from None
        if meta.get("format") != "scg-matchset":
            raise ValueError(f"{path}: not a match set")
        if (pairs.ndim != 2 or pairs.shape[1:] != (2,) or len(counts) != len(pairs)
                or pix_a.shape != pix_b.shape or pix_a.shape != (int(counts.sum()), 2)):
            raise ValueError(f"{path}: inconsistent match set arrays")
        offs = np.r_[0, np.cumsum(counts)]
        matches = {
            (int(i), int(j)): (pix_a[offs[k]:offs[k + 1]].astype(np.float32), pix_b[offs[k]:offs[k + 1]].astype(np.float32))
            for k, (i, j) in enumerate(pairs)
        }
        return cls(
            view_ids=view_ids,
            matches=matches,
            image_sizes={int(v): (int(w), int(h)) for v, w, h in sizes if w >= 0},
            warnings={(int(i), int(j)): str(w) for i, j, w in meta.get("warnings", [])},
            stats={(int(i), int(j)): {k: int(v) for k, v in s.items()} for i, j, s in meta.get("stats", [])},
            meta=meta.get("meta", {}),
        )
