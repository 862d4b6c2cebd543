"""evaaa/video.py: mp4 files are H.264 in yuv420p (what browsers play), GIFs are small, and both keep the frames."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import decode_mp4, video_stream
from PIL import Image

from evaaa.video import GifWriter, VideoSink, write_mp4


def frames(n: int, h: int = 64, w: int = 64) -> list[np.ndarray]:
    """``n`` frames, each a different flat grey with a moving bright square, so that they differ."""
    out = []
    for i in range(n):
        f = np.full((h, w, 3), 20 * i % 200, dtype=np.uint8)
        f[8:24, 2 * i : 2 * i + 16] = (250, 40, 40)
        out.append(f)
    return out


def test_write_mp4_writes_h264_in_yuv420p_that_decodes_to_its_frames(tmp_path):
    source = frames(12)
    path = write_mp4(tmp_path / "eye.mp4", source, fps=10)
    stream = video_stream(path)
    assert stream.startswith("h264"), stream  # OpenCV's mp4v (MPEG-4 part 2) plays in no browser
    assert "yuv420p" in stream and "64x64" in stream, stream
    decoded = decode_mp4(path)
    assert len(decoded) == len(source)
    for i, frame in enumerate(decoded):
        errors = [np.abs(frame.astype(int) - f.astype(int)).mean() for f in source]
        assert errors[i] == min(errors) and errors[i] < 10, (i, errors)


def test_an_odd_sized_video_is_padded_not_refused(tmp_path):
    # yuv420p needs even sides: a 65x63 picture is padded by a pixel, not rescaled or refused
    path = write_mp4(tmp_path / "odd.mp4", frames(3, h=63, w=65), fps=10)
    stream = video_stream(path)
    assert stream.startswith("h264") and "66x64" in stream, stream


def test_a_gif_keeps_every_nth_frame_scaled_down(tmp_path):
    gif = GifWriter(tmp_path / "a.gif", fps=10, every=2, scale=0.5)
    for f in frames(9, h=64, w=128):
        gif.write(f)
    gif.close()
    with Image.open(tmp_path / "a.gif") as image:
        assert image.format == "GIF" and image.size == (64, 32)
        assert image.n_frames == 5  # frames 0, 2, 4, 6, 8
        assert image.info["duration"] == 200 and image.info["loop"] == 0
        image.seek(4)
        last = np.asarray(image.convert("RGB"))
    assert (last[4:12, 8:12] == (250, 40, 40)).all()  # the square where frame 8 has it, colours exact


@pytest.mark.parametrize("every, scale", [(0, 0.5), (2, 0.0), (2, 1.5)])
def test_a_gif_refuses_settings_outside_their_range(tmp_path, every, scale):
    with pytest.raises(ValueError, match="every must be >= 1 and scale in"):
        GifWriter(tmp_path / "a.gif", every=every, scale=scale)


def test_the_video_sink_writes_h264_and_the_gif_beside_it(tmp_path):
    sink = VideoSink(tmp_path, (64, 64), gif=tmp_path / "media" / "demo.gif", gif_every=3, gif_scale=1.0)
    for f in frames(7):
        sink.write(f[:, :, ::-1].copy())  # the sink takes BGR frames, as OpenCV draws them
    sink.close()
    assert sink.kind == "mp4" and sink.note == "" and sink.path == tmp_path / "rollout.mp4"
    assert video_stream(sink.path).startswith("h264")
    assert len(decode_mp4(sink.path)) == 7
    with Image.open(tmp_path / "media" / "demo.gif") as image:
        assert image.n_frames == 3 and image.size == (64, 64)
