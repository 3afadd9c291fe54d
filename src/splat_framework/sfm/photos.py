"""A folder of photos as SfM reads it: listed in natural order, decoded, checked and staged."""

from __future__ import annotations

from pathlib import Path

from ..data.images import list_images as list_image_files
from ..data.images import read_photo
from ..errors import DataError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


def list_images(folder: Path) -> list[Path]:
    """The photos directly inside ``folder`` (suffixes :data:`IMAGE_SUFFIXES`), in natural order
    (``9`` before ``18``); a DataError when there are fewer than 2."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: not a folder of images")
    files = [p for p in list_image_files(folder) if p.suffix.lower() in IMAGE_SUFFIXES]
    if len(files) < 2:
        raise DataError(f"{folder}: {len(files)} image(s) found ({', '.join(IMAGE_SUFFIXES)}); at least 2 are needed")
    return files


def stage_images(images: list[Path], dest: Path) -> None:
    """Decode every image (EXIF orientation applied), check one common size, write them as PNG
    into ``dest`` under their own stem."""
    import cv2

    if len({p.stem for p in images}) != len(images):
        raise DataError(f"{images[0].parent}: two images share a name stem; rename them")
    dest.mkdir(parents=True)
    sizes: dict[tuple[int, int], list[str]] = {}
    unreadable = []
    for path in images:
        try:
            img = read_photo(path)  # decoded completely (a truncated JPEG is refused), EXIF orientation applied
        except DataError as e:
            unreadable.append(f"{path.name} ({str(e).removeprefix(f'{path}: ')})")
            continue
        sizes.setdefault((img.shape[1], img.shape[0]), []).append(path.name)
        cv2.imwrite(str(dest / f"{path.stem}.png"), img)
    if unreadable:
        raise DataError(f"{images[0].parent}: unreadable image(s): {', '.join(unreadable)}")
    if len(sizes) > 1:
        parts = "; ".join(f"{w}x{h}: {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}"
                          for (w, h), names in sizes.items())
        raise DataError(f"{images[0].parent}: images of different sizes or orientations ({parts}); "
                        "resize them to one size")
