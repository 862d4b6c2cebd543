"""Off-screen rendering of many worlds that share one model: one GL context, one scene, one camera.

``mujoco.Renderer`` renders one image per call and copies and flips it; an env step renders a frame per world, so
this class keeps the per-frame path to the three MuJoCo calls (update the scene, draw, read the pixels) and flips
the whole batch once.  Creating the GL context is the expensive part (~150 ms): build one per simulator, never on
reset.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np


def gl_error(exc: Exception) -> RuntimeError:
    """A rendering failure explained: what to install and which variable to set."""
    backend = os.environ.get("MUJOCO_GL", "(unset)")
    return RuntimeError(
        f"evaaa could not create an off-screen OpenGL context (MUJOCO_GL={backend}): {exc}\n"
        "Headless rendering needs EGL (Debian/Ubuntu: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri) "
        "or OSMesa (apt-get install libosmesa6, then MUJOCO_GL=osmesa). MUJOCO_GL must be set before mujoco "
        "is first imported; `import evaaa` sets MUJOCO_GL=egl when it is unset. `bash scripts/setup.sh` "
        "installs and checks everything."
    )


def _gl_context_class():
    """The GL context class for ``MUJOCO_GL``.

    MuJoCo picks its default context class once, when it is first imported; ``import torchrl.envs`` imports
    MuJoCo, so a program that imports TorchRL before evaaa would be left with GLFW, which needs a display.
    Choosing the class here from ``MUJOCO_GL`` (which ``import evaaa`` defaults to ``egl``) avoids that.
    """
    backend = os.environ.get("MUJOCO_GL", "").lower()
    if backend == "egl":
        from mujoco.egl import GLContext
    elif backend == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        GLContext = mujoco.GLContext
    return GLContext


_current_context = None  # the GL context made current last in this process (making one current costs ~20 us)


class BatchRenderer:
    """Renders fixed cameras of a model for any of its ``MjData`` into (N, H, W, 3) uint8 arrays."""

    def __init__(self, model: mujoco.MjModel, height: int, width: int, hidden_groups: tuple[int, ...] = (),
                 adjust=None):
        """``adjust(row, scene, context)``, if given, may change the scene (lights, flags) or the context (fog) of
        each frame after the scene is updated and before it is drawn: worlds that share a model can still
        differ in light."""
        self.model = model
        self._adjust = adjust
        self.height, self.width = height, width
        try:
            self._gl = _gl_context_class()(width, height)
            self._make_current()
            self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        except Exception as exc:  # noqa: BLE001 - every GL failure gets the same explanation
            raise gl_error(exc) from exc
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        if width > self._context.offWidth or height > self._context.offHeight:
            raise ValueError(f"image {width}x{height} exceeds the off-screen buffer "
                             f"{self._context.offWidth}x{self._context.offHeight}")
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
        self._option = mujoco.MjvOption()
        for group in hidden_groups:
            self._option.geomgroup[group] = 0
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._catmask = int(mujoco.mjtCatBit.mjCAT_ALL)

    def render(self, datas, camera_id: int, out: np.ndarray | None = None) -> np.ndarray:
        """Frames of ``camera_id`` for each data in ``datas``, upright, as (len(datas), H, W, 3) uint8."""
        if out is None:
            out = np.empty((len(datas), self.height, self.width, 3), dtype=np.uint8)
        if _current_context is not self._gl:
            self._make_current()
        self._camera.fixedcamid = camera_id
        model, scene, context, rect = self.model, self._scene, self._context, self._rect
        for row, data in enumerate(datas):
            mujoco.mjv_updateScene(model, data, self._option, None, self._camera, self._catmask, scene)
            if self._adjust is not None:
                self._adjust(row, scene, context)
            mujoco.mjr_render(rect, scene, context)
            mujoco.mjr_readPixels(out[row], None, rect, context)
        # OpenGL rows run bottom-up
        out[:] = out[:, ::-1]
        return out

    def _make_current(self) -> None:
        global _current_context
        self._gl.make_current()
        _current_context = self._gl

    def close(self) -> None:
        global _current_context
        if getattr(self, "_gl", None) is not None:
            # free the GL objects in their own context: freeing them in whichever context is current would
            # delete another renderer's textures and buffers
            self._gl.make_current()
            self._context.free()
            self._context = None
            self._gl.free()
            self._gl = None
            _current_context = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass
