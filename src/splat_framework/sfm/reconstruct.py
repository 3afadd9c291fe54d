"""Posed scenes from a user's own photos: structure from motion with pycolmap.

``estimate_scene(images, out)`` reads the photos (EXIF rotation applied by
OpenCV), checks that they are readable and of one size, extracts and matches
features (COLMAP's SIFT, or a registered photo matcher, see :mod:`.photo_matchers`),
maps them with COLMAP's incremental mapper (or the global one, GLOMAP, with
``mapper="global"``), undistorts to a pinhole camera and writes a COLMAP folder
(``images/``, ``sparse/0/``) that :func:`~splat_framework.data.parsers.colmap.load_colmap`
reads. The folder is built beside ``out`` and renamed into place at the end, so a
failure leaves nothing half-written.

A learned matcher's matches become COLMAP's keypoints and raw matches; COLMAP verifies
them (geometric_verification) and maps from them. Few wide-baseline photos are where
this matters: DTU scan37's 3 training views register 0 of 3 from SIFT, 3 of 3 from
ALIKED + LightGlue.
"""

from __future__ import annotations

import shutil
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import get_args

from ..config.data import PairChoice
from ..console import phase, say
from ..errors import DataError
from ..files.output_paths import PROCESSED_SCENE, check_output, install_output
from ..files.work_folder import scratch
from ..runtime.threads import machine_threads
from .colmap import load_pycolmap, verified_pair_counts, write_matches
from .pair_selection import EXHAUSTIVE_MAX_PHOTOS, all_pairs, choose_pairs, linked_groups
from .photo_matchers import AUTO_MATCHER, AUTO_PREFERRED, choose_matcher, load_matcher, photo_matchers, run_matcher
from .photos import stage_images
from .posing_record import write_posing_record

MAPPERS = ("incremental", "global")
PAIR_CHOICES = get_args(PairChoice)


@dataclass
class SfmSummary:
    images: int  # photos given
    registered: list[str]  # names of the photos with a pose
    points: int  # 3D points of the model
    reprojection_px: float  # mean reprojection error
    seconds: float
    mapper: str
    matcher: str = "sift"
    pair_matches: dict[tuple[str, str], int] = field(default_factory=dict)
    """Verified matches of every pair of photos, by file name."""
    photos: list[str] = field(default_factory=list)
    """The photos' file names, in the order given."""

    @property
    def unregistered(self) -> int:
        return self.images - len(self.registered)

    @property
    def left_out(self) -> list[str]:
        """The file names of the photos without a pose (left out of the scene)."""
        registered = set(self.registered)
        return [name for name in self.photos if Path(name).stem not in registered]

    def not_registered_lines(self) -> list[str]:
        """One line per photo left out: ``IMG_7.jpg not registered (left out of the scene): verified
        matches with IMG_1.jpg 3, IMG_2.jpg 0``, its verified matches with each other photo by file
        name; first, when the photos form groups with no verified match between them, one line
        naming every group and the one that was posed (:meth:`groups_line`)."""
        groups = self.groups_line()
        return ([groups] if groups else []) + [
            f"{name} not registered (left out of the scene): verified matches with "
            f"{describe_counts(self.matches_of(name), 'photos')}" for name in self.left_out]

    def groups(self) -> list[list[str]]:
        """The photos (file names) in groups joined by verified matches: a photo is in the group of
        every photo it shares a verified match with (directly or through others); largest first."""
        return linked_groups(self.photos, [pair for pair, n in self.pair_matches.items() if n > 0])

    def groups_line(self) -> str | None:
        """``the photos form 2 groups with no verified match between them: a.jpg, b.jpg, c.jpg (posed:
        the scene) and d.jpg, e.jpg (left out); ...``, or None when at most one group has two photos
        or more (a lone photo is named by its own line)."""
        groups = [g for g in self.groups() if len(g) > 1]
        if len(groups) < 2:
            return None
        registered = set(self.registered)

        def named(group: list[str]) -> str:
            posed = sum(Path(n).stem in registered for n in group)
            state = "posed: the scene" if posed == len(group) else "left out" if not posed else f"{posed} posed"
            return f"{', '.join(group)} ({state})"

        return (f"the photos form {len(groups)} groups with no verified match between them: "
                f"{' and '.join(named(g) for g in groups)}; photos of one place, each overlapping others, pose as one")

    def matches_of(self, photo: str) -> dict[str, int]:
        """The verified matches of ``photo`` with each other photo: {file name: count}, in the photos' order."""
        found = {b if a == photo else a: n for (a, b), n in self.pair_matches.items() if photo in (a, b)}
        return {name: found[name] for name in self.photos if name in found}

    def line(self, out: Path | str) -> str:
        """One line: what the pose estimation of ``out`` found."""
        return (f"{out}: {len(self.registered)} of {self.images} images registered, {self.points:,} points, "
                f"mean reprojection error {self.reprojection_px:.2f} px, {self.seconds:.1f} s ({self.mapper} mapper, "
                f"{self.matcher} matches)")


LISTED_EMPTY = 10
"""Up to this many pairs (or photos) without verified matches are named one by one; more are counted."""


def describe_counts(counts: dict[str, int], what: str) -> str:
    """``a.jpg-b.jpg 512, b.jpg-c.jpg 30, a.jpg-c.jpg 0``: verified matches by name (of a pair, or of
    a photo), those with matches first (beyond :data:`LISTED_EMPTY` without, those are counted
    instead of named: ``the other 12 pairs 0``, ``what`` saying what they are)."""
    kept = [f"{name} {n}" for name, n in counts.items() if n]
    empty = [f"{name} 0" for name, n in counts.items() if not n]
    if len(empty) > LISTED_EMPTY:
        empty = [f"the other {len(empty)} {what} 0"]
    return ", ".join(kept + empty)


def describe_pair_matches(pairs: dict[tuple[str, str], int]) -> str:
    """``a.jpg-b.jpg 512, b.jpg-c.jpg 30, a.jpg-c.jpg 0``: every pair's verified matches by file name."""
    return describe_counts({f"{a}-{b}": n for (a, b), n in pairs.items()}, "pairs")


def estimate_scene(images: list[Path], out: Path, *, mapper: str = "incremental", overwrite: bool = False,
                   camera_model: str = "SIMPLE_RADIAL", matcher: str = "sift", ordered: bool = False, pairs: str = "auto") -> SfmSummary:
    """Estimate intrinsics and poses of ``images`` and write the COLMAP scene folder ``out``.

    ``camera_model``: COLMAP's model shared by all photos (SIMPLE_RADIAL: one focal length,
    centred principal point, one radial distortion term, undistorted away when writing;
    SIMPLE_PINHOLE keeps the photos as they are). ``ordered``: the photos are the frames of a clip,
    in order (their neighbours in time are paired too; :func:`~.pair_selection.choose_pairs`, which
    matches every pair up to 10 photos and chosen pairs above). ``pairs``: "auto" (those chosen
    pairs) or "exhaustive" (every pair, whatever the count).

    Raises DataError (one line) when an image is unreadable, sizes differ, fewer than 2
    images register (the message gives the verified matches of every pair by file name),
    or ``out`` may not be written (see :mod:`splat_framework.files.output_paths`: a folder
    that splat-process did not write, the photos' folder, or, without ``overwrite``, an earlier scene)."""
    if mapper not in MAPPERS:
        raise DataError(f"--mapper must be one of {', '.join(MAPPERS)}, got {mapper!r}")
    if pairs not in PAIR_CHOICES:
        raise DataError(f"--pairs must be one of {', '.join(PAIR_CHOICES)}, got {pairs!r}")
    choose = pairs == "auto" and len(images) > EXHAUSTIVE_MAX_PHOTOS
    plugins = photo_matchers()
    auto = matcher == AUTO_MATCHER
    matcher = choose_matcher(matcher, plugins)
    match = load_matcher(matcher, plugins[matcher]) if matcher != "sift" else None  # before any work
    out = Path(out)
    check_output(out, PROCESSED_SCENE, overwrite=overwrite, inputs={Path(p).parent for p in images})
    pycolmap = load_pycolmap()
    t0 = time.perf_counter()
    with scratch(out) as work:  # removes those left by a run that crashed or was killed
        stage_images(images, work / "input")
        staged = [f"{Path(p).stem}.png" for p in images]
        original = dict(zip(staged, (Path(p).name for p in images)))
        db = work / "database.db"
        cpu = pycolmap.Device.cpu
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = camera_model
        with phase(f"feature extraction ({len(images)} photos)"):
            pycolmap.extract_features(db, work / "input", camera_mode=pycolmap.CameraMode.SINGLE,
                                      reader_options=reader, device=cpu)
        import cv2

        # decoded for a learned matcher, or to choose the pairs of more than a few photos
        rgb = ([cv2.imread(str(work / "input" / f), cv2.IMREAD_COLOR)[..., ::-1].copy() for f in staged]
               if matcher != "sift" or choose else None)
        chosen = pairs_to_match(rgb, ordered) if choose else all_pairs(len(staged))
        of_all = f"{len(chosen)} of {len(staged) * (len(staged) - 1) // 2} pairs"
        if matcher != "sift":
            try:
                # on the machine's cores whatever the load: the same matches (so poses) alone or not;
                # the matcher shows its own progress (the framework's: one phase naming the work)
                say(f"matching {of_all} with {matcher} for the poses")
                with machine_threads():
                    found = run_matcher(match, rgb, chosen, matcher)
                write_matches(pycolmap, db, staged, found)
            except FileNotFoundError as e:  # the matcher's weights are not installed
                if not auto:
                    raise
                warnings.warn(f"matcher auto: {e}; using SIFT", stacklevel=2)
                matcher = "sift"
        if matcher == "sift":
            with phase(f"matching (sift, {of_all})"):
                if len(chosen) == len(all_pairs(len(staged))):
                    pycolmap.match_exhaustive(db, device=cpu)
                else:  # COLMAP matches the listed pairs
                    listed = work / "pairs.txt"
                    listed.write_text("".join(f"{staged[a]} {staged[b]}\n" for a, b in chosen))
                    pycolmap.match_image_pairs(db, pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(listed)),
                                               device=cpu)
        pairs = {(original[a], original[b]): n for (a, b), n in verified_pair_counts(pycolmap, db, staged).items()}
        (work / "sparse").mkdir()
        with phase(f"mapping ({mapper})"):
            mapping = pycolmap.global_mapping if mapper == "global" else pycolmap.incremental_mapping
            models = mapping(db, work / "input", work / "sparse")
        best = max(models.values(), key=lambda r: r.num_reg_images(), default=None)
        registered = [best.images[i].name for i in best.reg_image_ids()] if best is not None else []
        if len(registered) < 2:
            raise DataError(
                f"{images[0].parent}: {len(registered)} of {len(images)} images registered "
                f"({mapper} mapper, {matcher} matches; verified matches per pair: {describe_pair_matches(pairs)}); "
                f"try photos with more overlap, more photos, "
                f"{'--matcher aliked-lightglue, ' if matcher == 'sift' and AUTO_PREFERRED in plugins else ''}"
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
        if matcher != "sift":  # the prior of a run on this scene takes its training pairs from here
            keep_pose_matches(pycolmap, best, sparse0, scene / "images", staged, found, matcher)
        summary = SfmSummary(
            images=len(images), registered=[Path(n).stem for n in staged if n in set(registered)],
            points=best.num_points3D(), reprojection_px=float(best.compute_mean_reprojection_error()),
            seconds=time.perf_counter() - t0, mapper=mapper, matcher=matcher, pair_matches=pairs,
            photos=[Path(p).name for p in images],
        )
        write_posing_record(scene, summary.photos, summary.left_out, matcher, mapper)
        install_output(scene, out, PROCESSED_SCENE)
        return summary


def pairs_to_match(rgb: list, ordered: bool) -> list[tuple[int, int]]:
    """The pairs of the photos ``rgb`` to match (:func:`~.pair_selection.choose_pairs`), with a phase
    line."""
    how = "by similarity and order in the clip" if ordered else "by similarity"
    with machine_threads(), phase(f"choosing pairs ({len(rgb)} photos, {how})"):
        return choose_pairs(rgb, ordered=ordered)


def keep_pose_matches(pycolmap, model, sparse0: Path, images: Path, staged: list[str],
                      found: dict[tuple[int, int], tuple], matcher: str) -> None:
    """Write the photo matcher's verified matches ``found`` ({(i, j): (pts_i, pts_j)} over ``staged``,
    in the photos' pixel coordinates) between registered photos into the scene folder (beside
    ``images``, the undistorted images), moved into the undistorted images' coordinates through
    ``model``'s cameras and the undistorted ones in ``sparse0``; only for a matcher the matching
    prior can take them from (:mod:`.pose_matches`)."""
    import numpy as np

    from ..config.matching import match_config
    from .pose_matches import POSE_MATCHES, REUSABLE, matcher_options, save_pose_matches

    if matcher not in REUSABLE:
        return
    distorted = {model.images[i].name: model.cameras[model.images[i].camera_id] for i in model.reg_image_ids()}
    undistorted = pycolmap.Reconstruction(sparse0)
    pinhole = {im.name: undistorted.cameras[im.camera_id] for im in undistorted.images.values()}

    def moved(name: str, pts) -> np.ndarray:
        cam, new = distorted[name], pinhole[name]
        normalised = np.asarray(cam.cam_from_img(np.asarray(pts, np.float64).reshape(-1, 2)), np.float64)
        return np.asarray(new.img_from_cam(np.hstack([normalised, np.ones((len(normalised), 1))])), np.float64)

    pairs = {}
    for (i, j), (pa, pb) in found.items():
        a, b = staged[i], staged[j]
        if a not in pinhole or b not in pinhole or len(pa) == 0:
            continue
        ua, ub = moved(a, pa), moved(b, pb)
        inside = np.ones(len(ua), bool)
        for name, u in ((a, ua), (b, ub)):
            cam = pinhole[name]
            inside &= np.isfinite(u).all(1) & (u[:, 0] >= 0) & (u[:, 0] <= cam.width) & (u[:, 1] >= 0) & (u[:, 1] <= cam.height)
        pairs[(a, b)] = (ua[inside], ub[inside])
    kept = {name: (images / name, (cam.width, cam.height)) for name, cam in pinhole.items()}
    save_pose_matches(images.parent / POSE_MATCHES, matcher, matcher_options(match_config(matcher)), kept, pairs)
