"""The benchmark protocol of estimated poses: a dataset's training views posed from their own photos alone."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ..errors import DataError
from .alignment import align_sim3, pose_errors
from .photo_matchers import AUTO_MATCHER
from .reconstruct import MAPPERS, estimate_scene


def estimate_training_poses(data: str | Path, *, views: int | str, format: str = "auto", downscale: float | None = None,
                            matcher: str = AUTO_MATCHER) -> dict:
    """The pose file (:mod:`splat_framework.data.pose_file`) of a dataset's training views posed
    from their own photos alone: the honest few-shot setting, where the dataset's poses (COLMAP
    on all of LLFF's 20 or DTU's 49 photos) are not available.

    Protocol (that of pose-free methods, e.g. BARF, Lin et al. ICCV 2021, sec. 4, and CF-3DGS,
    Fu et al. CVPR 2024): :func:`estimate_scene` poses the training photos (SIMPLE_PINHOLE, so
    that they need no undistortion; COLMAP's incremental mapper, or the global one, GLOMAP,
    when the incremental one leaves a view out: lego's 8 views around the object register
    4 of 8 incrementally, 7 or 8 of 8 globally, varying between runs) at the training resolution or at a quarter of the full
    resolution, whichever is larger (LLFF trains at 1/8 and ships 1/4: more pixels, more
    matches); :func:`align_sim3` moves the estimate into the dataset's frame by the similarity
    that best maps the estimated camera centres onto the dataset's training centres; the test
    views keep the dataset's poses and are scored after a test-time pose fit
    (``test_pose_steps``). ``info`` holds the SfM summary, the focal lengths (pixels at the
    training resolution) and :func:`pose_errors`.

    Raises DataError when not every training view registers."""
    from ..data.parsers import load_scene
    from ..data.parsers.colmap import load_colmap
    from ..data.pose_file import pose_file_payload
    from .own_photos import resolve_data_path

    root = resolve_data_path(data)
    scene = load_scene(root, format=format, views=views, downscale=downscale)
    if scene.undistort is not None:  # the photos are posed as SIMPLE_PINHOLE ones
        raise DataError(f"{root}: its lenses are distorted; estimated training poses need pinhole photos")
    train = list(scene.train_indices)
    quarter = load_scene(root, format=format, views=views, downscale=4.0)
    photos_of = quarter if quarter.cameras[train[0]].width > scene.cameras[train[0]].width else scene
    photos = [Path(photos_of.image_paths[i]) for i in train]
    with tempfile.TemporaryDirectory(prefix="splat-poses-") as tmp:
        for mapper in MAPPERS:  # incremental first; the global mapper when it leaves a view out
            try:
                summary = estimate_scene(photos, Path(tmp) / "sfm", camera_model="SIMPLE_PINHOLE", matcher=matcher,
                                         mapper=mapper, overwrite=True)
            except DataError as e:  # fewer than 2 registered
                summary, failure = None, str(e)
            if summary is not None and len(summary.registered) == len(photos):
                break
        if summary is None or len(summary.registered) < len(photos):
            got = ("; ".join([f"{len(summary.registered)} of {len(photos)}", *summary.not_registered_lines()])
                   if summary is not None else failure)
            raise DataError(f"{root}: training views not all registered by either mapper ({got})")
        est = load_colmap(Path(tmp) / "sfm")
    by_name = {Path(p).stem: c for p, c in zip(est.image_paths, est.cameras)}
    est_cams = [by_name[p.stem] for p in photos]
    est_w2c = np.stack([c.world_to_cam.double().numpy() for c in est_cams])
    true_w2c = np.stack([scene.cameras[i].world_to_cam.double().numpy() for i in train])
    aligned = align_sim3(est_w2c, true_w2c)
    cameras = {}
    for k, i in enumerate(train):
        c = est_cams[k]
        cameras[i] = replace(c, world_to_cam=torch.as_tensor(aligned[k], dtype=c.world_to_cam.dtype),
                             name=scene.cameras[i].name)
    info = {
        "data": str(data), "views": len(train), "registered": len(summary.registered), "points": summary.points,
        "reprojection_px": summary.reprojection_px, "sfm_seconds": summary.seconds, "matcher": summary.matcher,
        "mapper": summary.mapper,
        "sfm_size": [est_cams[0].width, est_cams[0].height],
        "focal_estimated": [float(c.K[0, 0]) * scene.cameras[i].width / c.width for c, i in zip(est_cams, train)],
        "focal_dataset": [float(scene.cameras[i].K[0, 0]) for i in train],
        **pose_errors(est_w2c, true_w2c),
    }
    return pose_file_payload(cameras, info)
