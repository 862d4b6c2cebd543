"""Where a simulator's physics and camera run, and the simulator of a backend: :func:`make_simulator`.

``cpu``: MuJoCo and OpenGL, world by world (:class:`evaaa.sim.Simulator`); ``warp``: MuJoCo Warp, every world at
once on a GPU or Warp's CPU device (:class:`evaaa.mjwarp.WarpSimulator`, the optional extra ``warp``, imported only
when asked for).
"""

from __future__ import annotations

from .level import Level
from .sim import Simulator

#: the backends :func:`make_simulator` knows
BACKENDS: tuple[str, ...] = ("cpu", "warp")


def check_backend(backend) -> str:
    """``backend`` if it names one of :data:`BACKENDS`, else a clear error."""
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(repr(b) for b in BACKENDS)}; got {backend!r}")
    return backend


def make_simulator(
    level: Level,
    num_worlds: int = 1,
    modalities=None,
    *,
    seed: int | None = None,
    threads: int | None = None,
    worlds: str = "train",
    backend: str = "cpu",
    device: str | None = None,
) -> Simulator:
    """A simulator of ``level`` on ``backend`` (:data:`BACKENDS`); ``device``: Warp's device for ``warp`` (None:
    the first GPU, else the CPU), ignored by ``cpu``."""
    if check_backend(backend) == "warp":
        from .mjwarp import WarpSimulator  # imports mujoco_warp: only when asked for

        return WarpSimulator(level, num_worlds, modalities, seed=seed, threads=threads, worlds=worlds, device=device)
    return Simulator(level, num_worlds, modalities, seed=seed, threads=threads, worlds=worlds)
