"""Few-shot train/test split rules, exactly as the published protocols use them.

See ``docs/data.md``. All functions return ``(train, test)`` as
sorted-as-specified lists of indices into the parser's camera list.

- LLFF / COLMAP / transforms.json / synthetic forward scenes (images sorted by name): test =
  every 8th image (0, 8, 16, ...); train = the remaining images at positions
  ``round(linspace(0, n_rest - 1, k))`` (Python ``round``: banker's rounding).
- Blender: 8 views from >= 94 train frames -> DietNeRF's [2, 16, 26, 55, 73,
  76, 86, 93]; other k -> the same linspace rule over the train frames; test =
  every 8th test frame.
- DTU (49 views): train = the first k of [25, 22, 28, 40, 44, 48, 0, 8, 13]
  (then the remaining non-test views in order); test = the fixed 25-view list.

``views="all"`` trains on every non-test image (the dense setting).

Validation views (``--eval-split val``; choose defaults on these, report the test views): every
view that is neither a training nor a test view (LLFF, DTU, one's own scenes); on Blender, every
8th frame of ``transforms_val.json``, or, without that file, of the training frames not trained on.

Without ``--views`` a scene trains on :func:`default_views`: the papers' few-shot
:data:`FEW_SHOT_VIEWS` on the benchmark formats, every view elsewhere (COLMAP and
transforms.json scenes: one's own captures).

A user's own scene (COLMAP, e.g. from ``splat-process``, or transforms.json) of only a
few photos is trained on all of them when holding out every 8th would leave fewer than
``views`` (:func:`own_scene_split`): three photos and ``--views 3`` train on the
three, and there is no test view to score; with ``views="all"`` (their default)
up to :data:`FEW_PHOTOS` photos all train.
"""

from __future__ import annotations

from typing import Literal, Sequence

import numpy as np

from .scene import DataError

Views = int | Literal["all"]

LLFF_HOLDOUT = 8
BLENDER_TEST_EVERY = 8
"""Blender scores every this-many-th frame of its test split (and of its val split, for validation)."""
BLENDER_DIETNERF_8 = [2, 16, 26, 55, 73, 76, 86, 93]
DTU_TRAIN_ORDER = [25, 22, 28, 40, 44, 48, 0, 8, 13]
FEW_PHOTOS = 8
"""Up to this many photos of one's own, ``views="all"`` trains on every one and holds none out."""
DTU_TEST = [1, 2, 9, 10, 11, 12, 14, 15, 23, 24, 26, 27, 29, 30, 31, 32, 33, 34, 35, 41, 42, 43, 45, 46, 47]
FEW_SHOT_FORMATS = ("llff", "blender", "dtu")
"""The benchmark formats, whose scenes train on a few-shot split unless ``--views`` says otherwise."""
FEW_SHOT_VIEWS = 3
"""Training views of the benchmark formats' default split (the papers' main setting)."""


def default_views(fmt: str) -> Views:
    """The training views of a scene of format ``fmt`` when ``--views`` is not given:
    :data:`FEW_SHOT_VIEWS` on the benchmarks (:data:`FEW_SHOT_FORMATS`), "all" on every other
    format (COLMAP, transforms.json: one's own scenes, every 8th image held out beyond
    :data:`FEW_PHOTOS`)."""
    return FEW_SHOT_VIEWS if fmt in FEW_SHOT_FORMATS else "all"


def check_views(views: object) -> Views:
    """Validate the ``views`` argument (a positive int or "all")."""
    if isinstance(views, str):
        if views == "all":
            return "all"
        if views.strip().isdigit():
            views = int(views.strip())
        else:
            raise DataError(f"views: expected a positive integer or 'all', got {views!r}")
    if isinstance(views, (bool, np.bool_)) or not isinstance(views, (int, np.integer)):
        raise DataError(f"views: expected a positive integer or 'all', got {views!r}")
    if views < 1:
        raise DataError(f"views: expected a positive integer or 'all', got {views}")
    return int(views)


def linspace_pick(pool: Sequence[int], k: int) -> list[int]:
    """``[pool[round(x)] for x in linspace(0, len(pool) - 1, k)]`` (Python round)."""
    n = len(pool)
    if k > n:
        raise DataError(f"views={k} is more than the {n} images in the training pool")
    return [pool[round(float(x))] for x in np.linspace(0, n - 1, k)]


def _too_many(k: int, n: int, what: str) -> DataError:
    return DataError(f"views={k} is more than the {n} images in the training pool ({what})")


def llff_split(n_images: int, views: Views = "all", holdout: int = LLFF_HOLDOUT) -> tuple[list[int], list[int]]:
    """Every-``holdout``-th test split over ``n_images`` images sorted by name."""
    views = check_views(views)
    if n_images < 1:
        raise DataError("no images to split")
    test = list(range(0, n_images, holdout)) if n_images > 1 else []
    test_set = set(test)
    rest = [i for i in range(n_images) if i not in test_set]
    if not rest:
        raise DataError(f"no training images left after holding out every {holdout}th of {n_images}")
    if views == "all":
        return rest, test
    if views > len(rest):
        raise _too_many(views, len(rest), f"{n_images} images minus {len(test)} held-out test views")
    return linspace_pick(rest, views), test


def own_scene_split(n_images: int, views: Views = "all") -> tuple[list[int], list[int]]:
    """:func:`llff_split`, except that a scene with at least ``views`` but too few images to also
    hold out test views is trained on ``views`` of them spread by the linspace rule, with no
    test view (a user's 3 photos and ``--views 3``), and that ``views="all"`` over at most
    :data:`FEW_PHOTOS` images trains on every one. Benchmark scenes always have enough images."""
    views = check_views(views)
    if views == "all" and n_images <= FEW_PHOTOS:
        return list(range(n_images)), []
    if views != "all" and n_images >= views and n_images - len(range(0, n_images, LLFF_HOLDOUT)) < views:
        return linspace_pick(list(range(n_images)), views), []
    return llff_split(n_images, views)


def blender_split(
    train_pool: Sequence[int], test_pool: Sequence[int], views: Views = "all", test_every: int = BLENDER_TEST_EVERY
) -> tuple[list[int], list[int]]:
    """Blender split; pools are camera indices of the train / test frames in file order."""
    views = check_views(views)
    train_pool, test_pool = list(train_pool), list(test_pool)
    test = test_pool[::test_every]
    if not train_pool:
        raise DataError("no training frames")
    if views == "all":
        return train_pool, test
    if views > len(train_pool):
        raise _too_many(views, len(train_pool), "frames in transforms_train.json")
    if views == 8 and len(train_pool) >= 94:
        return [train_pool[i] for i in BLENDER_DIETNERF_8], test
    return linspace_pick(train_pool, views), test


def dtu_split(n_images: int, views: Views = "all") -> tuple[list[int], list[int]]:
    """DTU split (RegNeRF protocol). Scenes with fewer than 49 views keep the
    protocol indices that exist."""
    views = check_views(views)
    test = [i for i in DTU_TEST if i < n_images]
    test_set = set(test)
    rest = [i for i in range(n_images) if i not in test_set]
    if not rest:
        raise DataError(f"no training views left among {n_images} DTU images")
    if views == "all":
        return rest, test
    if views > len(rest):
        raise _too_many(views, len(rest), f"{n_images} DTU images minus {len(test)} protocol test views")
    order = [i for i in DTU_TRAIN_ORDER if i < n_images]
    order += [i for i in rest if i not in set(order)]
    return order[:views], test
