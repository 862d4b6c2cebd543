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
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import cv2
import numpy as np
import torch
from torchrl.record.loggers import Logger

__all__ = ["VideoLogger", "write_mp4"]


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
