"""Posed scenes from a user's own photos: structure from motion with pycolmap.

``estimate_scene(images, out)`` reads the photos (EXIF rotation applied by
OpenCV), checks that they are readable and of one size, extracts and matches
SIFT features, maps them with COLMAP's incremental mapper (or the global one,
GLOMAP, with ``mapper="global"``), undistorts to a pinhole camera and writes a
COLMAP folder (``images/``, ``sparse/0/``) that :func:`load_colmap` reads. The
folder is built beside ``out`` and renamed into place at the end, so a failure
leaves nothing half-written.

pycolmap (PyPI; it ships COLMAP, runs on the CPU, downloads nothing) is an
optional dependency: ``pip install "splat[process]"``.

``matcher``: "auto" (aliked-lightglue where it is registered and its weights
are installed, else SIFT), COLMAP's own SIFT ("sift"), or a photo matcher registered
under the ``splat_framework.photo_matchers`` entry point group (the framework's
matching prior registers its learned ``aliked-lightglue`` and ``disk-lightglue``;
plugins may add more): a function
``match(images: list[[H, W, 3] uint8 RGB]) -> {(i, j): (pts_i [M, 2], pts_j [M, 2])}``
in continuous pixel coordinates (pixel centres at +0.5, COLMAP's convention). Its
matches become COLMAP's keypoints and raw matches; COLMAP verifies them
(geometric_verification) and maps from them. Few wide-baseline photos are where
this matters: DTU scan37's 3 training views register 0 of 3 from SIFT, 3 of 3
from ALIKED + LightGlue.
"""

from __future__ import annotations

import itertools
import shutil
import tempfile
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from .cameras import camera_centers, pose_differences
from .console import phase
from .data.images import read_photo
from .errors import DataError
from .files.output_paths import PROCESSED_SCENE, check_output, install_output
from .files.work_folder import make_work_folder, remove_stale_work_folders, remove_work_folder

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
MAPPERS = ("incremental", "global")
PHOTO_MATCHER_GROUP = "splat_framework.photo_matchers"
AUTO_MATCHER = "auto"  # AUTO_PREFERRED where registered and its weights are installed, else sift
AUTO_PREFERRED = "aliked-lightglue"


def photo_matchers() -> dict[str, object]:
    """Entry points of the registered photo matchers (the framework's and installed plugins'), by name (not loaded)."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=PHOTO_MATCHER_GROUP)}


def _write_matches(pycolmap, db_path: Path, names: list[str], matches: dict) -> None:
    """Replace the database's keypoints and matches with ``matches`` ({(i, j): (pts_i, pts_j)} over
    ``names``): each image's keypoints are the distinct points of its matches."""
    keypoints: list[dict[tuple[float, float], int]] = [{} for _ in names]

    def index(k: int, pts: np.ndarray) -> np.ndarray:
        table = keypoints[k]
        return np.array([table.setdefault((float(x), float(y)), len(table)) for x, y in pts], np.uint32)

    pairs = {(i, j): np.stack([index(i, pa), index(j, pb)], axis=1) for (i, j), (pa, pb) in matches.items() if len(pa)}
    db = pycolmap.Database.open(db_path)
    try:
        ids = {im.name: im.image_id for im in db.read_all_images()}
        for table in (db.clear_keypoints, db.clear_descriptors, db.clear_matches, db.clear_two_view_geometries):
            table()
        for k, name in enumerate(names):
            db.write_keypoints(ids[name], np.array(list(keypoints[k]), np.float32).reshape(-1, 2))
        for (i, j), m in pairs.items():
            db.write_matches(ids[names[i]], ids[names[j]], m)
    finally:
        db.close()
    pycolmap.geometric_verification(db_path, pairing_options=pycolmap.ExistingMatchedPairingOptions())


@dataclass
class SfmSummary:
    images: int  # photos given
    registered: list[str]  # names of the photos with a pose
    points: int  # 3D points of the model
    reprojection_px: float  # mean reprojection error
    seconds: float
    mapper: str
    matcher: str = "sift"

    @property
    def unregistered(self) -> int:
        return self.images - len(self.registered)


def _pycolmap():
    try:
        import pycolmap
    except ImportError:
        raise DataError('splat-process needs pycolmap: pip install "splat[process]"') from None
    # COLMAP's own per-step log lines; our summary and one-line errors say what happened
    pycolmap.logging.minloglevel = int(pycolmap.logging.Level.FATAL.value)
    return pycolmap


def list_images(folder: Path) -> list[Path]:
    """The image files directly inside ``folder``, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: not a folder of images")
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if len(files) < 2:
        raise DataError(f"{folder}: {len(files)} image(s) found ({', '.join(IMAGE_SUFFIXES)}); at least 2 are needed")
    return files


def _stage_images(images: list[Path], dest: Path) -> None:
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


def estimate_scene(images: list[Path], out: Path, *, mapper: str = "incremental", overwrite: bool = False,
                   camera_model: str = "SIMPLE_RADIAL", matcher: str = "sift") -> SfmSummary:
    """Estimate intrinsics and poses of ``images`` and write the COLMAP scene folder ``out``.

    ``camera_model``: COLMAP's model shared by all photos (SIMPLE_RADIAL: one focal length,
    centred principal point, one radial distortion term, undistorted away when writing;
    SIMPLE_PINHOLE keeps the photos as they are).

    Raises DataError (one line) when an image is unreadable, sizes differ, fewer than 2
    images register, or ``out`` may not be written (see :mod:`splat_framework.files.output_paths`: a folder
    that splat-process did not write, the photos' folder, or, without ``overwrite``, an earlier scene)."""
    if mapper not in MAPPERS:
        raise DataError(f"--mapper must be one of {', '.join(MAPPERS)}, got {mapper!r}")
    plugins = photo_matchers()
    auto = matcher == AUTO_MATCHER
    if auto:
        matcher = AUTO_PREFERRED if AUTO_PREFERRED in plugins else "sift"
    if matcher != "sift" and matcher not in plugins:
        raise DataError(f"--matcher must be one of {', '.join(['auto', 'sift', *sorted(plugins)])}, got {matcher!r}")
    out = Path(out)
    check_output(out, PROCESSED_SCENE, overwrite=overwrite, inputs={Path(p).parent for p in images})
    pycolmap = _pycolmap()
    t0 = time.perf_counter()
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_work_folders(out)  # left by a run that crashed or was killed
    work = make_work_folder(out)
    try:
        _stage_images(images, work / "input")
        db = work / "database.db"
        cpu = pycolmap.Device.cpu
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = camera_model
        with phase(f"feature extraction ({len(images)} photos)"):
            pycolmap.extract_features(db, work / "input", camera_mode=pycolmap.CameraMode.SINGLE,
                                      reader_options=reader, device=cpu)
        if matcher != "sift":
            import cv2

            staged = sorted((work / "input").iterdir())
            rgb = [cv2.imread(str(f), cv2.IMREAD_COLOR)[..., ::-1].copy() for f in staged]
            try:
                with phase(f"matching ({matcher}, {len(rgb) * (len(rgb) - 1) // 2} pairs)"):
                    _write_matches(pycolmap, db, [f.name for f in staged], plugins[matcher].load()(rgb))
            except FileNotFoundError as e:  # the matcher's weights are not installed
                if not auto:
                    raise
                warnings.warn(f"matcher auto: {e}; using SIFT", stacklevel=2)
                matcher = "sift"
        if matcher == "sift":
            with phase(f"matching (sift, {len(images) * (len(images) - 1) // 2} pairs)"):
                pycolmap.match_exhaustive(db, device=cpu)
        (work / "sparse").mkdir()
        with phase(f"mapping ({mapper})"):
            mapping = pycolmap.global_mapping if mapper == "global" else pycolmap.incremental_mapping
            models = mapping(db, work / "input", work / "sparse")
        best = max(models.values(), key=lambda r: r.num_reg_images(), default=None)
        registered = sorted(best.images[i].name for i in best.reg_image_ids()) if best is not None else []
        if len(registered) < 2:
            raise DataError(
                f"{images[0].parent}: {len(registered)} of {len(images)} images registered "
                f"({mapper} mapper, {matcher} matches); try photos with more overlap, more photos, "
                f"{'--matcher aliked-lightglue, ' if matcher == 'sift' and 'aliked-lightglue' in plugins else ''}"
                f"or --mapper {'incremental' if mapper == 'global' else 'global'}")
        model_dir = work / "model"
        model_dir.mkdir()
        best.write(model_dir)
        scene = work / "scene"
        with phase("undistortion"):
            pycolmap.undistort_images(scene, model_dir, work / "input")  # pinhole: images/, sparse/
        sparse0 = scene / "sparse" / "0"
        sparse0.mkdir()
        for f in list((scene / "sparse").iterdir()):
            if f.is_file():
                f.rename(sparse0 / f.name)
        for extra in ("stereo", "run-colmap-geometric.sh", "run-colmap-photometric.sh"):
            p = scene / extra
            shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
        summary = SfmSummary(
            images=len(images), registered=[Path(n).stem for n in registered], points=best.num_points3D(),
            reprojection_px=float(best.compute_mean_reprojection_error()),
            seconds=time.perf_counter() - t0, mapper=mapper, matcher=matcher,
        )
        install_output(scene, out, PROCESSED_SCENE)
        return summary
    finally:
        remove_work_folder(work)


def pick_video_frames(video: Path, n: int, dest: Path) -> list[Path]:
    """Write ``n`` frames of ``video`` spread along it into ``dest`` (created) as PNG: the video is
    cut into ``n`` equal spans and the sharpest frame of each (largest variance of the Laplacian
    of its grey image) is kept. Raises DataError when the video cannot be read or has fewer than
    ``n`` frames."""
    import cv2

    if n < 2:
        raise DataError(f"--frames must be >= 2, got {n}")
    def frames():
        cap = cv2.VideoCapture(str(video))
        if not cap.isOpened():
            raise DataError(f"{video}: not a video OpenCV can read")
        try:
            while True:
                ok, frame = cap.read()
                if not ok:
                    return
                yield frame
        finally:
            cap.release()

    # two decoding passes, so that only one frame is in memory at a time (the frame count
    # a container declares is not reliable enough to cut the spans by)
    sharpness = [float(cv2.Laplacian(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY), cv2.CV_64F).var()) for f in frames()]
    total = len(sharpness)
    if total < n:
        raise DataError(f"{video}: {total} frame(s) decoded, fewer than --frames {n}; ask for fewer frames")
    spans = np.arange(total) * n // total
    keep = {int(np.flatnonzero(spans == k)[np.argmax(np.asarray(sharpness)[spans == k])]) for k in range(n)}
    dest.mkdir(parents=True)
    paths = []
    for i, frame in enumerate(frames()):
        if i in keep:
            paths.append(dest / f"frame{i:06d}.png")
            cv2.imwrite(str(paths[-1]), frame)
    return paths


def align_sim3(est_w2c: np.ndarray, true_w2c: np.ndarray) -> np.ndarray:
    """World-to-camera matrices [M, 4, 4] of the estimated cameras moved into the true cameras'
    frame by the similarity that best maps their centres onto the true ones (Umeyama,
    ``pycolmap.estimate_sim3d``); the true frame's units."""
    pycolmap = _pycolmap()
    sim = pycolmap.estimate_sim3d(camera_centers(est_w2c), camera_centers(true_w2c))
    if sim is None:
        raise DataError("the estimated camera centres are degenerate; no similarity aligns them")
    m = np.asarray(sim.matrix())  # [3, 4] = [s R | t]: x_true = s R x_est + t
    out = np.tile(np.eye(4), (len(est_w2c), 1, 1))
    out[:, :3, :3] = est_w2c[:, :3, :3] @ (m[:, :3] / float(sim.scale)).T
    out[:, :3, 3] = -np.einsum("nij,nj->ni", out[:, :3, :3], camera_centers(est_w2c) @ m[:, :3].T + m[:, 3])
    return out


def sim3_errors(est_w2c: np.ndarray, true_w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose errors after :func:`align_sim3`: (rotation errors in degrees [M], camera-centre
    errors [M] in the true frame's units) of world-to-camera matrices [M, 3 or 4, 4]."""
    return pose_differences(align_sim3(est_w2c, true_w2c), true_w2c)


def pose_errors(est_w2c: np.ndarray, true_w2c: np.ndarray) -> dict:
    """Errors of estimated world-to-camera matrices [M, 4, 4] against the true ones (lists of
    floats): ``rotation_deg`` and ``center_error_rel_spread`` (centre error over the extent of
    the true centres) after :func:`align_sim3`, and ``translation_direction_deg``, the angle
    between estimated and true direction from camera i to camera j, seen from camera i, over
    every ordered pair (scale- and frame-free)."""
    rot, center = sim3_errors(est_w2c, true_w2c)

    def directions(w2c: np.ndarray) -> list[np.ndarray]:
        c = camera_centers(w2c)
        t = [w2c[i, :3, :3] @ (c[j] - c[i]) for i, j in itertools.permutations(range(len(w2c)), 2)]
        return [v / np.linalg.norm(v) for v in t]

    dirs = [float(np.degrees(np.arccos(np.clip(a @ b, -1, 1)))) for a, b in zip(directions(est_w2c), directions(true_w2c))]
    true_c = camera_centers(true_w2c)
    spread = np.linalg.norm(true_c.max(0) - true_c.min(0))
    return {"rotation_deg": rot.tolist(), "translation_direction_deg": dirs,
            "center_error_rel_spread": (center / spread).tolist()}


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
    from .data import load_scene, resolve_data_path
    from .data.parsers.colmap import load_colmap
    from .data.pose_file import pose_file_payload

    root = resolve_data_path(data)
    scene = load_scene(root, format=format, views=views, downscale=downscale)
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
            got = f"{len(summary.registered)} of {len(photos)}" if summary is not None else failure
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


__all__ = ["MAPPERS", "SfmSummary", "align_sim3", "camera_centers", "estimate_scene", "estimate_training_poses",
           "list_images", "pick_video_frames", "pose_errors", "sim3_errors"]
