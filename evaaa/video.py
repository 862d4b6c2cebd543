"""Videos of the agent's view, for TorchRL and gymnasium users: H.264 mp4 that browsers play, and animated GIFs.

mp4 files are H.264 (yuv420p), written by the ffmpeg that ships inside the ``imageio-ffmpeg`` wheel (a dependency);
where it cannot run, OpenCV's MPEG-4 part 2 (``mp4v``) stands in, which players decode and browsers do not.  GIFs are
written with Pillow (which matplotlib already needs).

TorchRL's ``VideoRecorder`` transform collects frames and hands them to a logger; TorchRL's own loggers write mp4
through torchcodec or torchvision, which are not installed with evaaa.  :class:`VideoLogger` is a TorchRL logger
that writes them here instead:

>>> from torchrl.envs import TransformedEnv
>>> from torchrl.record import VideoRecorder
>>> logger = VideoLogger("videos", fps=10)
>>> env = TransformedEnv(evaaa.make_env("1-1", seed=0), VideoRecorder(logger, tag="eye", in_keys=["pixels"]))
>>> env.rollout(200, break_when_any_done=False)
>>> env.transform.dump()                    # writes videos/eye_0.mp4

For the gymnasium adapter, :func:`write_mp4` writes the frames of ``env.render()`` (``render_mode="rgb_array"``).
:class:`VideoSink` writes frames as they are drawn (``scripts/demo.py``), and optionally a small GIF beside them.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import cv2
import numpy as np
import torch
from torchrl.record.loggers import Logger

__all__ = ["GifWriter", "Mp4Writer", "VideoLogger", "VideoSink", "write_mp4"]


class Mp4Writer:
    """Writes RGB frames (H, W, 3) uint8 of one size to an mp4 file, one at a time: H.264 (yuv420p, ``+faststart``
    so a browser starts playing before the whole file arrives) through imageio-ffmpeg's ffmpeg, or, where that
    cannot start, OpenCV's mp4v.  :attr:`codec` says which (``h264`` or ``mp4v``), :attr:`note` why not H.264."""

    def __init__(self, path: str | os.PathLike, size_wh: tuple[int, int], fps: float = 10.0):
        self.path = Path(path)
        self.size = (int(size_wh[0]), int(size_wh[1]))
        self.note = ""
        self._ffmpeg = self._cv2 = None
        try:
            import imageio_ffmpeg

            self._ffmpeg = imageio_ffmpeg.write_frames(
                str(self.path),
                self.size,
                fps=float(fps),
                codec="libx264",
                pix_fmt_in="rgb24",
                pix_fmt_out="yuv420p",
                # yuv420p needs even sides: pad an odd one by a pixel (never rescale the picture)
                macro_block_size=1,
                output_params=["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-movflags", "+faststart", "-crf", "20"],
                ffmpeg_log_level="error",
            )
            self._ffmpeg.send(None)  # starts ffmpeg: a missing or broken binary fails here
            self.codec = "h264"
        except Exception as exc:  # noqa: BLE001 - no imageio-ffmpeg, no runnable ffmpeg: OpenCV's encoder instead
            self._ffmpeg = None
            self.note = f"H.264 unavailable ({type(exc).__name__}: {str(exc).strip()[:120]}); wrote mp4v"
            self._cv2 = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), self.size)
            if not self._cv2.isOpened():
                self._cv2.release()
                self.path.unlink(missing_ok=True)
                raise RuntimeError(f"cannot write an mp4 file at {self.path}: {self.note}") from None
            self.codec = "mp4v"

    def write(self, frame_rgb: np.ndarray) -> None:
        if (frame_rgb.shape[1], frame_rgb.shape[0]) != self.size:
            raise ValueError(
                f"a frame is {frame_rgb.shape[1]}x{frame_rgb.shape[0]}, the video {self.size[0]}x{self.size[1]}"
            )
        if self._ffmpeg is not None:
            self._ffmpeg.send(np.ascontiguousarray(frame_rgb))
        else:
            self._cv2.write(cv2.cvtColor(frame_rgb, cv2.COLOR_RGB2BGR))

    def close(self) -> None:
        if self._ffmpeg is not None:
            self._ffmpeg.close()
            self._ffmpeg = None
        if self._cv2 is not None:
            self._cv2.release()
            self._cv2 = None


class GifWriter:
    """An animated GIF of every ``every``-th RGB frame scaled by ``scale`` (small enough for a README): frames are
    kept in memory and written on :meth:`close`, all with one palette drawn from up to 32 of them, undithered (flat
    colours compress well and do not flicker)."""

    def __init__(self, path: str | os.PathLike, fps: float = 10.0, every: int = 2, scale: float = 0.5):
        if every < 1 or not 0 < scale <= 1:
            raise ValueError(f"GIF: every must be >= 1 and scale in (0, 1], got every={every}, scale={scale}")
        self.path = Path(path)
        self.every, self.scale = int(every), float(scale)
        self.duration_ms = round(1000 * self.every / fps)
        self._frames: list[np.ndarray] = []
        self._seen = 0

    def write(self, frame_rgb: np.ndarray) -> None:
        if self._seen % self.every == 0:
            if self.scale != 1:
                h, w = frame_rgb.shape[:2]
                size = (max(1, round(w * self.scale)), max(1, round(h * self.scale)))
                frame_rgb = cv2.resize(frame_rgb, size, interpolation=cv2.INTER_AREA)
            self._frames.append(np.ascontiguousarray(frame_rgb))
        self._seen += 1

    def close(self) -> None:
        if not self._frames:
            return
        from PIL import Image

        sample = self._frames[:: max(1, len(self._frames) // 32)]
        palette = Image.fromarray(np.concatenate(sample, axis=0)).quantize(colors=255, dither=Image.Dither.NONE)
        images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in self._frames]
        self.path.parent.mkdir(parents=True, exist_ok=True)
        images[0].save(
            self.path, save_all=True, append_images=images[1:], duration=self.duration_ms, loop=0, optimize=True
        )
        self._frames = []


def write_mp4(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float = 10.0) -> Path:
    """Write RGB frames, each (H, W, 3) uint8 of one size, to an H.264 mp4 file (:class:`Mp4Writer`); returns the
    path."""
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
                writer = Mp4Writer(path, (frame.shape[1], frame.shape[0]), fps)
            elif (frame.shape[1], frame.shape[0]) != writer.size:
                size = writer.size
                raise ValueError(f"frame {count} is {frame.shape[1]}x{frame.shape[0]}, the video {size[0]}x{size[1]}")
            writer.write(frame)
            count += 1
    finally:
        if writer is not None:
            writer.close()
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
    """Writes BGR frames one at a time to ``<out>/rollout.mp4`` (H.264, else mp4v: :class:`Mp4Writer`), falling back
    to PNG frames where no mp4 can be written, and to ``gif`` too when given (:class:`GifWriter`: every
    ``gif_every``-th frame scaled by ``gif_scale``).  ``kind`` says which (``mp4`` or ``png``), ``note`` why not
    H.264 (empty for H.264)."""

    def __init__(
        self,
        out: Path,
        size_wh: tuple[int, int],
        fps: float = 10.0,
        *,
        gif: Path | None = None,
        gif_every: int = 2,
        gif_scale: float = 0.5,
    ):
        self.out = out
        self.kind = "mp4"
        self.path = out / "rollout.mp4"
        self.note = ""
        self.frames = 0
        self.gif = None if gif is None else GifWriter(gif, fps, gif_every, gif_scale)
        self._mp4 = None
        try:
            self._mp4 = Mp4Writer(self.path, size_wh, fps)
            self.note = self._mp4.note
        except RuntimeError as exc:
            self.path = out / "rollout_frames"
            self.path.mkdir(parents=True, exist_ok=True)
            self.kind = "png"
            self.note = f"no mp4 could be written ({exc}); wrote PNG frames"

    def write(self, frame_bgr: np.ndarray) -> None:
        if self._mp4 is not None or self.gif is not None:
            rgb = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB)
        if self._mp4 is not None:
            self._mp4.write(rgb)
        else:
            cv2.imwrite(str(self.path / f"frame_{self.frames:05d}.png"), frame_bgr)
        if self.gif is not None:
            self.gif.write(rgb)
        self.frames += 1

    def close(self) -> None:
        if self._mp4 is not None:
            self._mp4.close()
        if self.gif is not None:
            self.gif.close()
