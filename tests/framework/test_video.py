"""mp4 files that browsers play: H.264 / yuv420p through PyAV, OpenCV's mp4v with a notice without it."""

import numpy as np
import pytest

from splat_framework.export import video


def frames(n, h, w):
    """Smooth colour ramps with a moving bright square (what renders look like, unlike noise)."""
    y, x = np.mgrid[0:h, 0:w]
    out = []
    for i in range(n):
        f = np.stack([255 * x / w, 255 * y / h, np.full((h, w), 128.0)], -1)
        f[10:20, 5 + 4 * i: 15 + 4 * i] = 255
        out.append(f.astype(np.uint8))
    return out


def probe(path):
    """(codec, pixel format, frame count, width, height) of the first video stream, decoded by FFmpeg."""
    import av

    with av.open(str(path)) as c:
        s = c.streams.video[0]
        decoded = [f.to_ndarray(format="rgb24") for f in c.decode(s)]
        return s.codec_context.name, s.codec_context.format.name, len(decoded), s.width, s.height, decoded


def test_h264_yuv420p_even_at_odd_sizes(tmp_path):
    pytest.importorskip("av")
    if not video.h264_available():
        pytest.skip("PyAV without libx264")
    src = frames(7, 49, 65)
    with video.open_video(tmp_path / "v.mp4", 12, 65, 49) as v:
        for f in src:
            v.write(f)
    codec, fmt, n, w, h, decoded = probe(tmp_path / "v.mp4")
    assert (codec, fmt, n, w, h) == ("h264", "yuv420p", 7, 66, 50)  # padded by one edge pixel
    err = np.abs(decoded[3][:49, :65].astype(int) - src[3].astype(int)).mean()
    assert err < 3, err  # the content survives (CRF 18)
    with pytest.raises(ValueError, match=r"v2.mp4: frame is \(49, 64, 3\)"):
        with video.open_video(tmp_path / "v2.mp4", 12, 65, 49) as v:
            v.write(np.zeros((49, 64, 3), np.uint8))


def test_without_pyav_opencv_writes_mp4v_and_says_so(tmp_path, monkeypatch):
    import cv2

    monkeypatch.setattr(video, "h264_available", lambda: False)
    with pytest.warns(UserWarning, match="pip install av"):
        v = video.open_video(tmp_path / "v.mp4", 12, 64, 48)
    with v:
        for f in frames(5, 48, 64):
            v.write(f)
    cap = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode()
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert fourcc in ("mp4v", "FMP4") and n == 5  # MPEG-4 Part 2, whichever tag OpenCV reads back
