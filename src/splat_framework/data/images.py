"""Image, mask and depth-map decoding (OpenCV), with one-line DataErrors.

Every function here raises :class:`DataError` ("<path>: <problem>") for a
missing, unreadable, truncated or otherwise undecodable file; nothing else
escapes. ``cv2`` is imported lazily so that importing the data package stays
cheap for CLIs that only parse arguments.
"""

from __future__ import annotations

import os
import re
import struct
import tempfile
import threading
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from ..cameras import scaled_size
from .scene import DataError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".exr")


def image_file_problem(path: Path) -> str | None:
    """Why ``path`` cannot be read as an image file ("image file not found", "not a regular file (a
    FIFO)", ...), None when it is a regular file: a FIFO or a device exists but is never opened."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "image file not found"
    except OSError as e:
        return f"cannot be read ({e.strerror or e})"
    if stat.S_ISREG(mode):
        return None
    kind = ("a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a device")
    return f"not a regular file ({kind})"


def check_image_file(path: Path, listed: str = "") -> None:
    """A DataError naming ``path`` (and where it is ``listed``) unless it is a regular file."""
    problem = image_file_problem(path)
    if problem is not None:
        raise DataError(f"{path}: {problem}" + (f" ({listed})" if listed else ""))


def _read_bytes(path: Path) -> bytes:
    path = Path(path)
    check_image_file(path)
    try:
        return path.read_bytes()
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None


def _header_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG or JPEG header, or None if not recognised."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        if len(data) < 24 or data[12:16] != b"IHDR":
            return None
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if data[:2] == b"\xff\xd8":
        i = 2
        n = len(data)
        while i + 4 <= n:
            if data[i] != 0xFF:
                return None
            marker = data[i + 1]
            if marker == 0xFF:  # fill byte
                i += 1
                continue
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
                i += 2
                continue
            (seglen,) = struct.unpack(">H", data[i + 2 : i + 4])
            # SOF0..SOF15 except DHT (C4), JPG (C8), DAC (CC)
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
                if i + 9 > n:
                    return None
                h, w = struct.unpack(">HH", data[i + 5 : i + 9])
                return int(w), int(h)
            i += 2 + seglen
        return None
    return None


def read_image_size(path: Path | str) -> tuple[int, int]:
    """(width, height) of an image file as stored.

    Reads only the header for PNG and JPEG; other formats are decoded.
    """
    path = Path(path)
    check_image_file(path)
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None
    size = _header_size(head)
    if size is not None:
        if size[0] <= 0 or size[1] <= 0:
            raise DataError(f"{path}: image header gives an empty size {size[0]}x{size[1]}")
        return size
    if len(head) == 0:
        raise DataError(f"{path}: empty image file")
    arr = _decode(path, _read_bytes(path))
    return int(arr.shape[1]), int(arr.shape[0])


def _decode(path: Path, data: bytes, flags: int | None = None) -> np.ndarray:
    """Decode an image file's bytes completely (``flags``: OpenCV's, default IMREAD_UNCHANGED);
    an empty, truncated or undecodable file is a DataError naming ``path``."""
    import cv2

    if len(data) == 0:
        raise DataError(f"{path}: empty image file")
    if data[:2] == b"\xff\xd8":
        # libjpeg decodes a truncated file with a grey tail and only a warning.
        tail = data[-4096:] if len(data) > 8192 else data[len(data) // 2 :]
        if b"\xff\xd9" not in tail:
            raise DataError(f"{path}: truncated JPEG (no end-of-image marker)")
    if data[:8] == b"\x89PNG\r\n\x1a\n" and b"IEND" not in data[-64:]:
        raise DataError(f"{path}: truncated PNG (no IEND chunk)")
    buf = np.frombuffer(data, dtype=np.uint8)
    try:
        with _decoder_messages() as complaints:
            arr = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED if flags is None else flags)
    except cv2.error as e:  # pragma: no cover - depends on codec
        raise DataError(f"{path}: cannot decode image ({str(e).strip().splitlines()[-1]})") from None
    if data[:2] == b"\xff\xd8" and complaints:  # libjpeg says so only of corrupt data, which it decodes as garbage
        raise DataError(f"{path}: corrupt JPEG ({complaints[0]})")
    if arr is None or arr.size == 0:
        why = complaints[0] if complaints else "corrupt or unsupported format"
        raise DataError(f"{path}: cannot decode image ({why})")
    return arr


_DECODER_STDERR = threading.Lock()


@contextmanager
def _decoder_messages() -> Iterator[list[str]]:
    """Inside, what the image libraries print on the process's stderr (file descriptor 2: libjpeg's
    ``Corrupt JPEG data: ...``, libpng's errors) is kept instead of shown; the list holds its lines
    after the block, for the one-line error that names the file. One decode at a time: the
    descriptor is the process's."""
    lines: list[str] = []
    with _DECODER_STDERR, tempfile.TemporaryFile() as sink:
        try:
            saved = os.dup(2)
        except OSError:  # no stderr at all: nothing to keep off it
            yield lines
            return
        os.dup2(sink.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            lines += [line.strip() for line in sink.read().decode("utf-8", "replace").splitlines() if line.strip()]


def read_photo(path: Path | str) -> np.ndarray:
    """A photo as 8-bit BGR [H, W, 3], its EXIF orientation applied, decoded completely:
    a missing, empty, truncated (JPEG without its end-of-image marker, PNG without IEND)
    or undecodable file is a DataError naming it, never a photo with a grey tail."""
    import cv2

    path = Path(path)
    return _decode(path, _read_bytes(path), cv2.IMREAD_COLOR)


def _to_float(path: Path, arr: np.ndarray) -> np.ndarray:
    if arr.dtype == np.uint8:
        return arr.astype(np.float32) / 255.0
    if arr.dtype == np.uint16:
        return arr.astype(np.float32) / 65535.0
    if arr.dtype in (np.float32, np.float64, np.float16):
        out = arr.astype(np.float32)
        if not np.isfinite(out).all():
            raise DataError(f"{path}: image contains non-finite values")
        return out
    raise DataError(f"{path}: unsupported pixel type {arr.dtype}")


def load_image(
    path: Path | str, *, scale: float = 1.0, white_background: bool = False
) -> np.ndarray:
    """Decode an image to float32 RGB in [0, 1].

    Args:
        path: image file (PNG, JPEG, ...; 8- or 16-bit; gray, RGB or RGBA).
        scale: resize factor (INTER_AREA when shrinking); the output size is
            :func:`scaled_size` of the stored size.
        white_background: composite an alpha channel on white (else black).
            Compositing happens before resizing.

    Returns:
        [H, W, 3] float32 array in [0, 1].
    """
    path = Path(path)
    if not (scale > 0 and np.isfinite(scale)):
        raise DataError(f"{path}: invalid image scale {scale!r}")
    arr = _decode(path, _read_bytes(path))
    img = _to_float(path, arr)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.ndim == 3:
        c = img.shape[2]
        if c == 1:
            img = np.repeat(img, 3, axis=2)
        elif c == 2:
            gray, alpha = img[:, :, :1], img[:, :, 1:2]
            bg = 1.0 if white_background else 0.0
            img = np.repeat(gray * alpha + bg * (1.0 - alpha), 3, axis=2)
        elif c == 3:
            img = img[:, :, ::-1]
        elif c == 4:
            rgb, alpha = img[:, :, 2::-1], img[:, :, 3:4]
            bg = 1.0 if white_background else 0.0
            img = rgb * alpha + bg * (1.0 - alpha)
        else:
            raise DataError(f"{path}: unsupported channel count {c}")
    else:
        raise DataError(f"{path}: unsupported image shape {arr.shape}")
    return _rescale(np.ascontiguousarray(img, dtype=np.float32), scale)


def _rescale(img: np.ndarray, scale: float) -> np.ndarray:
    """[H, W(, C)] float32 resized by ``scale`` (INTER_AREA when shrinking), clipped to [0, 1]."""
    import cv2

    if scale != 1.0:
        h, w = img.shape[:2]
        size = scaled_size(w, h, scale)
        if size != (w, h):
            interp = cv2.INTER_AREA if scale < 1.0 else cv2.INTER_LINEAR
            img = cv2.resize(img, size, interpolation=interp)
    return np.clip(img, 0.0, 1.0)


def load_alpha(path: Path | str, *, scale: float = 1.0) -> np.ndarray | None:
    """The image's own alpha channel as float32 [H, W] in [0, 1], or None when it has none.

    Same size as :func:`load_image` with the same ``scale``. RGBA renders such
    as Blender's carry their foreground mask this way (0 = background).
    """
    path = Path(path)
    if not (scale > 0 and np.isfinite(scale)):
        raise DataError(f"{path}: invalid image scale {scale!r}")
    arr = _decode(path, _read_bytes(path))
    if arr.ndim != 3 or arr.shape[2] not in (2, 4):
        return None
    return _rescale(np.ascontiguousarray(_to_float(path, arr)[:, :, -1]), scale)


BACKDROP_LEVEL = 30 / 255
"""A backdrop pixel's brightest channel is below this (the public SCGaussian/DNGaussian DTU rule)."""
BACKDROP_RUN = 1 / 6
"""... and so are the pixels above it over this fraction of the image height (50 rows of DTU's 300)."""


def dark_backdrop_mask(image: np.ndarray, level: float = BACKDROP_LEVEL, run: float = BACKDROP_RUN) -> np.ndarray:
    """[H, W] bool: the unlit backdrop of an [H, W, 3] image in [0, 1] (DTU's black studio background).

    A pixel is backdrop when its brightest channel is below ``level`` and so is
    every pixel above it in the same column, up to ``run`` * H rows (fewer at the
    top edge). Dark parts of an object lit from above (a black handle under a
    bright table edge) fail the run and are kept. This is the rule of the public
    SCGaussian code (``train.py``: max channel < 30/255 and the 49 rows above,
    at 400x300), written relative to the image height so it holds at any scale.
    """
    if image.ndim != 3 or image.shape[2] < 3:
        raise ValueError(f"expected an [H, W, 3] image, got shape {image.shape}")
    dark = image[:, :, :3].max(axis=2) < level
    h = dark.shape[0]
    n = max(1, int(round(run * h)))
    # dark pixels in the window [max(0, y - n + 1), y] of each column, from a cumulative sum
    c = np.concatenate([np.zeros((1, dark.shape[1]), np.int64), np.cumsum(dark, axis=0)])
    rows = np.arange(h)
    top = np.maximum(rows - n + 1, 0)
    return (c[rows + 1] - c[top]) == (rows + 1 - top)[:, None]


def load_mask(path: Path | str, size: tuple[int, int]) -> np.ndarray:
    """Decode a foreground mask to float32 [H, W] in [0, 1] at ``size`` = (W, H).

    Any channel layout works (the channel mean is taken). Values stay soft, as
    the DTU protocol needs: 1 = object, fractions on its edge (see
    :mod:`splat_framework.evaluation.metrics`). Masks at another resolution are resized
    with area averaging.
    """
    import cv2

    path = Path(path)
    img = load_image(path)
    m = img.mean(axis=2)
    w, h = size
    if m.shape != (h, w):
        m = cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(m, 0.0, 1.0).astype(np.float32)


def load_depth(path: Path | str, size: tuple[int, int]) -> np.ndarray:
    """Load a ``.npy`` depth map (camera z, 0 = no surface) as float32 [H, W] at ``size``.

    Maps stored at another resolution are resized with nearest-neighbour
    sampling (depth is not averaged across edges).
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: depth file not found")
    try:
        d = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - any decoding failure is bad input
        raise DataError(f"{path}: cannot read depth map ({type(e).__name__}: {e})".splitlines()[0]) from None
    if not isinstance(d, np.ndarray) or d.dtype.kind not in "fiu":
        raise DataError(f"{path}: depth map must be a numeric array")
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[:, :, 0]
    if d.ndim != 2 or d.shape[0] == 0 or d.shape[1] == 0:
        raise DataError(f"{path}: depth map must have shape [H, W], got {list(d.shape)}")
    d = d.astype(np.float32)
    d[~np.isfinite(d)] = 0.0
    w, h = size
    if d.shape != (h, w):
        d = cv2.resize(d, (w, h), interpolation=cv2.INTER_NEAREST)
    return d


def natural_key(name: str) -> tuple:
    """Sort key of a file name in natural order: digit runs compare as numbers (``9`` before
    ``18``), the rest case-insensitively; the name itself breaks ties (``01`` and ``1``)."""
    parts = re.split(r"(\d+)", name)
    return tuple(int(t) if k % 2 else t.casefold() for k, t in enumerate(parts)), name


def list_images(folder: Path, *, natural: bool = True) -> list[Path]:
    """Image files directly in ``folder`` (hidden files skipped), in natural order (:func:`natural_key`),
    or by plain name with ``natural=False`` (the order that LLFF's and DTU's pose files follow). A
    special file named like an image (a FIFO, a link to a device) is skipped with one warning naming
    it, never opened; a folder so named is skipped."""
    if not folder.is_dir():
        raise DataError(f"{folder}: image folder not found")
    files = []
    for p in folder.iterdir():
        if p.name.startswith(".") or p.suffix.lower() not in IMAGE_SUFFIXES or p.is_dir():
            continue
        problem = image_file_problem(p)
        if problem is None:
            files.append(p)
        else:
            warnings.warn(f"{p}: {problem}; skipped", stacklevel=2)
    return sorted(files, key=lambda p: natural_key(p.name) if natural else p.name)
