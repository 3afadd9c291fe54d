"""Writing mp4 videos that browsers play: H.264 in yuv420p through PyAV, OpenCV's mp4v as a fallback.

Chrome, Firefox and Safari play H.264 (High profile, yuv420p) mp4 files; they do
not play MPEG-4 Part 2 (OpenCV's ``mp4v``). PyAV (``av`` on PyPI) ships FFmpeg
with libx264 in its wheels, so :func:`open_video` encodes H.264 when it is
installed and falls back to OpenCV's writer with a one-line notice otherwise.

Usage::

    with open_video(path, fps=30, width=w, height=h) as video:
        for frame in frames:          # [H, W, 3] uint8 RGB
            video.write(frame)
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

__all__ = ["H264_OPTIONS", "open_video"]

H264_OPTIONS = {"crf": "18", "preset": "medium"}
"""libx264 settings: CRF 18 is visually lossless for renders; ``medium`` is x264's default speed."""


class _Writer:
    """A video being written; frames are [H, W, 3] uint8 RGB of the size it was opened with."""

    codec = ""

    def __init__(self, path: Path, fps: int, width: int, height: int) -> None:
        self.path, self.fps, self.width, self.height = Path(path), int(fps), int(width), int(height)

    def _check(self, frame: np.ndarray) -> np.ndarray:
        if frame.shape != (self.height, self.width, 3) or frame.dtype != np.uint8:
            raise ValueError(
                f"{self.path}: frame is {frame.shape} {frame.dtype}, expected ({self.height}, {self.width}, 3) uint8"
            )
        return np.ascontiguousarray(frame)

    def write(self, frame: np.ndarray) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> "_Writer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _H264Writer(_Writer):
    """libx264 through PyAV; odd sizes are padded by one edge pixel (yuv420p needs even sizes)."""

    codec = "h264"

    def __init__(self, path: Path, fps: int, width: int, height: int) -> None:
        import av

        super().__init__(path, fps, width, height)
        self._container = av.open(str(self.path), mode="w", format="mp4", options={"movflags": "+faststart"})
        try:
            stream = self._container.add_stream("libx264", rate=self.fps, options=dict(H264_OPTIONS))
            stream.width, stream.height = width + width % 2, height + height % 2
            stream.pix_fmt = "yuv420p"
        except BaseException:
            self._container.close()
            raise
        self._stream = stream
        self._frame_type = av.VideoFrame
        self._closed = False

    def write(self, frame: np.ndarray) -> None:
        frame = self._check(frame)
        if self.width % 2 or self.height % 2:
            frame = np.pad(frame, ((0, self.height % 2), (0, self.width % 2), (0, 0)), mode="edge")
        for packet in self._stream.encode(self._frame_type.from_ndarray(frame, format="rgb24")):
            self._container.mux(packet)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            for packet in self._stream.encode():  # flush the encoder
                self._container.mux(packet)
        finally:
            self._container.close()


class _OpenCVWriter(_Writer):
    """OpenCV's MPEG-4 Part 2 (``mp4v``) writer: plays in VLC / ffplay, not in web browsers."""

    codec = "mpeg4"

    def __init__(self, path: Path, fps: int, width: int, height: int) -> None:
        import cv2

        super().__init__(path, fps, width, height)
        self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, (width, height))
        if not self._writer.isOpened():
            raise RuntimeError(f"{self.path}: OpenCV cannot open an mp4 writer")

    def write(self, frame: np.ndarray) -> None:
        self._writer.write(np.ascontiguousarray(self._check(frame)[..., ::-1]))

    def close(self) -> None:
        self._writer.release()


def h264_available() -> bool:
    """Whether PyAV with the libx264 encoder can be imported."""
    try:
        import av
    except ImportError:
        return False
    return "libx264" in av.codecs_available


def open_video(path: Path, fps: int, width: int, height: int) -> _Writer:
    """An mp4 writer at ``path``: H.264 / yuv420p (browser-playable) through PyAV when it has
    libx264, else OpenCV's mp4v with a one-line warning saying how to get H.264."""
    if h264_available():
        return _H264Writer(path, fps, width, height)
    warnings.warn(
        f"{path}: PyAV with libx264 is not installed (pip install av), so this mp4 is MPEG-4 Part 2, "
        "which web browsers do not play",
        stacklevel=2,
    )
    return _OpenCVWriter(path, fps, width, height)
