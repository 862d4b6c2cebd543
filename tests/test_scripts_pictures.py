"""Smoke tests of the picture-making scripts: scripts/render_levels.py and scripts/demo.py, run in-process."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest
from helpers import load_script, video_stream
from PIL import Image

import evaaa  # noqa: F401  (sets MUJOCO_GL before mujoco, and so cv2's users, load)


def read_png(path: Path):
    assert path.is_file(), f"{path} was not written"
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, f"{path} is not a readable image"
    return img


def test_render_levels_writes_pictures(tmp_path, capsys):
    render_levels = load_script("render_levels")
    assert render_levels.main(["levels=[1-1]", f"out={tmp_path}", "seed=0"]) == 0
    printed = capsys.readouterr().out

    eye = read_png(tmp_path / "1-1_eye.png")
    assert eye.shape == (256, 256, 3)  # 64x64 upscaled x4
    # nearest-neighbour upscaling: every 4x4 block is one colour
    assert (eye[::4, ::4] == eye[3::4, 3::4]).all()
    assert read_png(tmp_path / "1-1_top.png").shape == (512, 512, 3)
    thermal = read_png(tmp_path / "1-1_thermal.png")
    overview = read_png(tmp_path / "1-1_overview.png")
    assert thermal.shape[0] > 200 and thermal.shape[1] > 200
    assert overview.shape[1] > 2 * overview.shape[0]  # three panels side by side
    for suffix in ("eye", "top", "thermal", "overview"):
        assert f"1-1_{suffix}.png" in printed


def test_render_levels_rejects_unknown_level(tmp_path, capsys):
    render_levels = load_script("render_levels")
    with pytest.raises(SystemExit) as exc:
        render_levels.main(["levels=no-such-level", f"out={tmp_path}"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "no-such-level" in err
    for name in evaaa.LEVELS:
        assert name in err, f"the error should list the available levels: {err}"
    assert not list(tmp_path.iterdir()), "nothing should be written for an invalid level"


def test_demo_writes_video_and_plots(tmp_path, capsys):
    demo = load_script("demo")
    assert demo.main(["level=1-1", "steps=40", "num_envs=1", "seed=0", f"out={tmp_path}"]) == 0
    printed = capsys.readouterr().out
    assert "steps/s" in printed

    video = tmp_path / "rollout.mp4"
    assert video.is_file() and video.stat().st_size > 0, "rollout.mp4 was not written"
    assert video_stream(video).startswith("h264"), "browsers play H.264 mp4, not mp4v"
    assert "note:" not in printed
    cap = cv2.VideoCapture(str(video))
    try:
        assert cap.isOpened(), "rollout.mp4 cannot be opened"
        frames = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if frames == 0:
                first_shape = frame.shape
            frames += 1
    finally:
        cap.release()
    assert frames >= 1
    assert first_shape[0] == 256  # the eye upscaled x4 sets the height

    final = read_png(tmp_path / "final_frame.png")
    assert final.shape == first_shape
    traces = read_png(tmp_path / "ev_traces.png")
    assert traces.shape[0] > 200 and traces.shape[1] > 200


def test_demo_plays_a_zoo_network_and_writes_a_small_gif(tmp_path, capsys):
    demo = load_script("demo")
    gif = tmp_path / "media" / "ppo.gif"
    argv = ["policy=zoo:ppo-1-1", "level=1-1", "steps=12", f"out={tmp_path / 'out'}", f"gif={gif}", "gif_every=3"]
    assert demo.main(argv) == 0
    printed = capsys.readouterr()
    assert "zoo:ppo-1-1" in printed.err  # the progress bar names the policy
    assert str(gif) in printed.out
    video = tmp_path / "out" / "rollout.mp4"
    assert video_stream(video).startswith("h264")
    with Image.open(gif) as image:
        first_width = read_png(tmp_path / "out" / "final_frame.png").shape[1]
        assert image.n_frames == 4 and image.size[0] == first_width // 2  # every 3rd of 12 frames, half size


def test_demo_refuses_a_policy_it_does_not_know_in_one_line(tmp_path, capsys):
    demo = load_script("demo")
    for policy, expected in [
        ("zoo:ppo1-1", "did you mean zoo:ppo-1-1?"),
        ("greedy", "expected oracle, random, still, zoo:NAME or an existing checkpoint file"),
    ]:
        with pytest.raises(SystemExit) as exc:
            demo.main([f"policy={policy}", f"out={tmp_path / 'out'}"])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and err.count("\n") == 1 and expected in err, err
    assert not (tmp_path / "out").exists()
