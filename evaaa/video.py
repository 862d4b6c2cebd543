"""Videos of the agent's view, written with OpenCV (a dependency already), for TorchRL and gymnasium users.

TorchRL's ``VideoRecorder`` transform collects frames and hands them to a logger; TorchRL's own loggers write mp4
through torchcodec or torchvision, which are not installed with evaaa.  :class:`VideoLogger` is a TorchRL logger
that writes them with OpenCV instead:

>>> from torchrl.envs import TransformedEnv
>>> from torchrl.record import VideoRecorder
>>> logger = VideoLogger("videos", fps=10)
>>> env = TransformedEnv(evaaa.make_env("1-1", seed=0), VideoRecorder(logger, tag="eye", in_keys=["pixels"]))
>>> env.rollout(200, break_when_any_done=False)
>>> env.transform.dump()                    # writes videos/eye_0.mp4

For the gymnasium adapter, :func:`write_mp4` writes the frames of ``env.render()`` (``render_mode="rgb_array"``).
:class:`VideoSink` writes frames as they are drawn (``scripts/demo.py``), with fallbacks where mp4 cannot be
written.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import cv2
import numpy as np
import torch
from torchrl.record.loggers import Logger

__all__ = ["VideoLogger", "VideoSink", "write_mp4"]


def write_mp4(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float = 10.0) -> Path:
    """Write RGB frames, each (H, W, 3) uint8 of one size, to an mp4 file (MPEG-4 part 2); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = None
    count = 0
    try:
        for frame in frames:
            frame = np.asarray(frame)
            if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
                raise ValueError(f"frames must be (H, W, 3) uint8 RGB images, got {frame.shape} {frame.dtype}")
            if writer is None:
                size = (frame.shape[1], frame.shape[0])
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), size)
                if not writer.isOpened():
                    raise RuntimeError(f"OpenCV cannot write an mp4 file at {path}")
            elif (frame.shape[1], frame.shape[0]) != size:
                raise ValueError(f"frame {count} is {frame.shape[1]}x{frame.shape[0]}, the video {size[0]}x{size[1]}")
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
            count += 1
    finally:
        if writer is not None:
            writer.release()
    if count == 0:
        raise ValueError("no frames to write")
    return path


class VideoLogger(Logger):
    """A TorchRL logger that writes the videos given to :meth:`log_video` as ``<log_dir>/<name>_<step>.mp4``.

    Only videos are written (scalars, hyperparameters and histograms are ignored): pair it with the run's own
    logger.  Videos arrive as TorchRL's ``VideoRecorder`` sends them, uint8 ``(1, T, C, H, W)`` or ``(T, C, H, W)``.
    """

    def __init__(self, log_dir: str | os.PathLike, fps: float = 10.0, exp_name: str = "evaaa"):
        self.fps = fps
        self.written: list[Path] = []
        super().__init__(exp_name=exp_name, log_dir=str(log_dir))

    def _create_experiment(self) -> Path:
        return Path(self.log_dir)

    def log_video(self, name: str, video: torch.Tensor, step: int | None = None, **kwargs) -> None:
        frames = torch.as_tensor(video)
        while frames.ndim > 4 and frames.shape[0] == 1:
            frames = frames[0]
        if frames.ndim != 4 or frames.shape[1] != 3:
            raise ValueError(f"expected a video of shape (T, 3, H, W) (or (1, T, 3, H, W)), got {tuple(video.shape)}")
        path = Path(self.log_dir) / f"{name}_{0 if step is None else step}.mp4"
        rgb = frames.permute(0, 2, 3, 1).to(torch.uint8).cpu().numpy()
        self.written.append(write_mp4(path, rgb, kwargs.get("fps", self.fps)))

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        pass

    def log_hparams(self, cfg) -> None:
        pass

    def log_histogram(self, name: str, data: Sequence, **kwargs) -> None:
        pass

    def __repr__(self) -> str:
        return f"VideoLogger(log_dir={str(self.log_dir)!r}, fps={self.fps})"


class VideoSink:
    """Writes BGR frames one at a time to ``<out>/rollout.mp4`` (mp4v); falls back to an animated GIF (imageio) or,
    last, PNG frames.  ``kind`` says which, ``note`` why (empty for mp4)."""

    def __init__(self, out: Path, size_wh: tuple[int, int], fps: float = 10.0):
        self.out = out
        self.kind = "mp4"
        self.path = out / "rollout.mp4"
        self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size_wh)
        self._gif = None
        self.note = ""
        self.frames = 0
        if not self._writer.isOpened():
            self._writer.release()
            self.path.unlink(missing_ok=True)
            try:
                import imageio.v2 as imageio

                self.path = out / "rollout.gif"
                self._gif = imageio.get_writer(self.path, mode="I", duration=1 / fps, loop=0)
                self.kind = "gif"
                self.note = "OpenCV could not open an mp4v writer; wrote an animated GIF instead"
            except Exception as exc:  # noqa: BLE001 - any failure means: fall back to PNG frames
                self.path = out / "rollout_frames"
                self.path.mkdir(parents=True, exist_ok=True)
                self.kind = "png"
                self.note = f"neither mp4 (OpenCV) nor GIF (imageio: {exc}) could be written; wrote PNG frames"

    def write(self, frame_bgr: np.ndarray) -> None:
        if self.kind == "mp4":
            self._writer.write(frame_bgr)
        elif self.kind == "gif":
            self._gif.append_data(cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB))
        else:
            cv2.imwrite(str(self.path / f"frame_{self.frames:05d}.png"), frame_bgr)
        self.frames += 1

    def close(self) -> None:
        if self.kind == "mp4":
            self._writer.release()
        elif self.kind == "gif":
            self._gif.close()
