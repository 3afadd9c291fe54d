"""Export trained Gaussians in the 3DGS reference PLY layout, and read such files back.

Layout (what ``GaussianModel.save_ply`` of the 3DGS reference writes and
common splat viewers read; the header also carries the comment line
``comment written by splat-export``, by which splat-export recognises its own
files before replacing one): one ``vertex`` element, binary little-endian,
every property ``float`` (float32), in this order::

    x y z                      position (ray-based Gaussians: their true position)
    nx ny nz                   zeros
    f_dc_0 f_dc_1 f_dc_2       degree-0 SH coefficient (R, G, B)
    f_rest_0 .. f_rest_{3(K-1)-1}
                               higher SH coefficients, channel-major:
                               f_rest_{c * (K-1) + k} = shN[:, k, c]
    opacity                    opacity logit (before the sigmoid)
    scale_0 scale_1 scale_2    log-scales (before the exp)
    rot_0 rot_1 rot_2 rot_3    rotation quaternion w, x, y, z (as stored, unnormalised)

Method-specific parameter keys (SCGaussian's ``z``, ``ray_o``, ``ray_d``,
``is_ray``, ``is_match``) are not exported: a viewer only needs the standard
Gaussian attributes.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import DataError
from ..files.output_paths import PLY_COMMENT
from ..runtime.io import atomic_write_bytes

__all__ = ["export_ply", "gaussians_for_export", "load_ply", "ply_property_names", "write_ply"]

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def ply_property_names(num_rest_coeffs: int) -> list[str]:
    """Vertex property names of the 3DGS layout; ``num_rest_coeffs`` = K - 1 (15 for SH degree 3)."""
    return (
        ["x", "y", "z", "nx", "ny", "nz"]
        + [f"f_dc_{i}" for i in range(3)]
        + [f"f_rest_{i}" for i in range(3 * num_rest_coeffs)]
        + ["opacity"]
        + [f"scale_{i}" for i in range(3)]
        + [f"rot_{i}" for i in range(4)]
    )


@torch.no_grad()
def gaussians_for_export(model) -> dict[str, Tensor]:
    """``model.export_gaussians()`` on the CPU in float32 (see
    :meth:`splat_framework.model.gaussians.GaussianModel.export_gaussians`)."""
    return {k: v.detach().float().cpu().contiguous() for k, v in model.export_gaussians().items()}


def write_ply(path: Path, gaussians: dict[str, Tensor]) -> Path:
    """Write ``gaussians`` (keys as returned by :func:`gaussians_for_export`) as a 3DGS PLY, atomically."""
    g = {k: torch.as_tensor(v).detach().float().cpu().numpy() for k, v in gaussians.items()}
    n = g["means"].shape[0]
    shN = g["shN"].reshape(n, *(g["shN"].shape[1:] if g["shN"].ndim == 3 else (-1, 3)))  # [N, K-1, 3], N may be 0
    k1 = shN.shape[1]
    names = ply_property_names(k1)
    columns = np.concatenate(
        [
            g["means"].reshape(n, 3),
            np.zeros((n, 3), np.float32),
            g["sh0"].reshape(n, 3),
            shN.transpose(0, 2, 1).reshape(n, 3 * k1),  # channel-major, as the reference
            g["opacities"].reshape(n, 1),
            g["scales"].reshape(n, 3),
            g["quats"].reshape(n, 4),
        ],
        axis=1,
    ).astype(np.float32)
    if not np.isfinite(columns).all():
        raise ValueError(f"{path}: refusing to export non-finite Gaussian parameters")
    vertex = np.empty(n, dtype=[(name, "<f4") for name in names])
    for i, name in enumerate(names):
        vertex[name] = columns[:, i]
    header = "\n".join(
        ["ply", "format binary_little_endian 1.0", PLY_COMMENT, f"element vertex {n}"]
        + [f"property float {name}" for name in names]
        + ["end_header"]
    ) + "\n"
    atomic_write_bytes(Path(path), header.encode("ascii") + vertex.tobytes())
    return Path(path)


def export_ply(model, path: Path) -> Path:
    """Write ``model``'s Gaussians to ``path`` in the 3DGS PLY layout."""
    return write_ply(path, gaussians_for_export(model))


_MAX_HEADER_LINES = 10_000


def _read_header(f, path: Path) -> tuple[str, int, list[tuple[str, str]], list[str]]:
    if f.readline().strip() != b"ply":
        raise DataError(f"{path}: not a PLY file")
    fmt, n_vertex, props, order = None, None, [], []
    element = None
    for lineno in range(2, _MAX_HEADER_LINES + 2):
        line = f.readline()
        if not line:
            raise DataError(f"{path}: PLY header has no end_header")
        words = line.decode("ascii", "replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                element = words[1]
                order.append(element)
                if element == "vertex":
                    n_vertex = int(words[2])
                    if n_vertex < 0:
                        raise ValueError("negative count")
                elif n_vertex is None:
                    raise DataError(f"{path}: PLY element '{element}' before 'vertex' is not supported")
            elif words[0] == "property" and element == "vertex":
                if words[1] == "list":
                    raise DataError(f"{path}: list properties in 'vertex' are not supported")
                if words[1] not in _PLY_TYPES:
                    raise DataError(f"{path}: unknown PLY property type '{words[1]}'")
                if any(words[2] == name for name, _ in props):
                    raise DataError(f"{path}: PLY property '{words[2]}' appears twice")
                props.append((words[2], _PLY_TYPES[words[1]]))
        except (IndexError, ValueError):
            shown = line[:80].decode("ascii", "replace").strip()
            raise DataError(f"{path}: malformed PLY header line {lineno}: {shown!r}") from None
    else:
        raise DataError(f"{path}: PLY header has no end_header within {_MAX_HEADER_LINES} lines")
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise DataError(f"{path}: PLY format '{fmt}' is not supported (binary only)")
    if n_vertex is None:
        raise DataError(f"{path}: PLY file has no vertex element")
    return fmt, n_vertex, props, [p for p, _ in props]


def load_ply(path: Path, device: str | torch.device = "cpu") -> dict[str, Tensor]:
    """Read a 3DGS-layout PLY (as written by :func:`export_ply` or the 3DGS reference).

    Returns:
        dict of float32 tensors in the parameter conventions of
        ``GaussianModel.params``: means [N, 3], quats [N, 4] (wxyz, as stored),
        scales [N, 3] (log), opacities [N] (logit), sh0 [N, 1, 3],
        shN [N, K-1, 3] (K-1 = number of f_rest properties / 3; may be 0).
    """
    path = Path(path)
    try:
        f = open(path, "rb")
    except OSError as e:
        raise DataError(f"{path}: cannot open PLY file ({e.strerror})") from None
    with f:
        fmt, n, props, names = _read_header(f, path)
        endian = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(name, endian + t) for name, t in props])
        available = os.fstat(f.fileno()).st_size - f.tell()
        if n * dtype.itemsize > available:  # checked before allocating anything of that size
            raise DataError(f"{path}: PLY file is truncated ({available} of {n * dtype.itemsize} vertex bytes)")
        data = f.read(n * dtype.itemsize)
    v = np.frombuffer(data, dtype=dtype, count=n)
    required = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"] + [f"scale_{i}" for i in range(3)] + [
        f"rot_{i}" for i in range(4)
    ]
    missing = [r for r in required if r not in names]
    if missing:
        raise DataError(f"{path}: not a Gaussian-splat PLY (missing {', '.join(missing)})")
    rest = [p for p in names if p.startswith("f_rest_")]
    if sorted(rest) != sorted(f"f_rest_{i}" for i in range(len(rest))):
        raise DataError(f"{path}: f_rest properties are not f_rest_0 ... f_rest_{len(rest) - 1}")
    rest = [f"f_rest_{i}" for i in range(len(rest))]
    if len(rest) % 3:
        raise DataError(f"{path}: {len(rest)} f_rest properties is not a multiple of 3")
    k1 = len(rest) // 3

    def cols(keys: list[str]) -> np.ndarray:
        if not keys:
            return np.zeros((n, 0), np.float32)
        return np.stack([v[k].astype(np.float32) for k in keys], axis=1)

    shN = cols(rest).reshape(n, 3, k1).transpose(0, 2, 1)
    out = {
        "means": cols(["x", "y", "z"]),
        "quats": cols([f"rot_{i}" for i in range(4)]),
        "scales": cols([f"scale_{i}" for i in range(3)]),
        "opacities": v["opacity"].astype(np.float32),
        "sh0": cols(["f_dc_0", "f_dc_1", "f_dc_2"]).reshape(n, 1, 3),
        "shN": shN,
    }
    return {k: torch.from_numpy(np.ascontiguousarray(a)).to(device) for k, a in out.items()}
