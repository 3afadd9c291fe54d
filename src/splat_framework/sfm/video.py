"""Frames of a video for pose estimation: spread along it, the sharpest of each span."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError


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
