"""COLMAP through pycolmap: the import (an optional dependency), matches written into COLMAP's
database, and the verified match counts it holds per pair of photos."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError


def load_pycolmap():
    """The pycolmap module, COLMAP's own log lines silenced (our summaries and one-line errors say
    what happened); a DataError naming the install command when it is missing. Importing it installs
    glog's failure handler for SIGTERM (a 40-line stack dump, then death): the handler the process
    had (the CLI's, a stop like Ctrl-C) is put back."""
    import signal
    import threading

    main_thread = threading.current_thread() is threading.main_thread()
    term = signal.getsignal(signal.SIGTERM) if main_thread else None
    try:
        import pycolmap
    except ImportError:
        raise DataError('pose estimation needs pycolmap: pip install "splat-framework[process]"') from None
    if term is not None:
        signal.signal(signal.SIGTERM, term)
    pycolmap.logging.minloglevel = int(pycolmap.logging.Level.FATAL.value)
    return pycolmap


def write_matches(pycolmap, db_path: Path, names: list[str], matches: dict) -> None:
    """Replace the database's keypoints and matches with ``matches`` ({(i, j): (pts_i [M, 2], pts_j [M, 2])}
    over ``names``) and verify them (``geometric_verification``): each image's keypoints are the
    distinct points of its matches."""
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


def verified_pair_counts(pycolmap, db_path: Path, names: list[str]) -> dict[tuple[str, str], int]:
    """Geometrically verified matches of every pair of the photos ``names`` (file names in the
    database), in the order of ``names``: {(name_i, name_j): count}, i < j, 0 where COLMAP kept none."""
    db = pycolmap.Database.open(db_path)
    try:
        by_id = {im.image_id: im.name for im in db.read_all_images()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
    finally:
        db.close()
    found = {}
    for pair_id, n in zip(pair_ids, inliers):
        a, b = (by_id.get(i) for i in pycolmap.pair_id_to_image_pair(pair_id))
        found[frozenset((a, b))] = int(n)
    return {(a, b): found.get(frozenset((a, b)), 0) for k, a in enumerate(names) for b in names[k + 1:]}
