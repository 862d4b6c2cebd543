"""Off-screen rendering of many worlds that share one model: one GL context, one scene, one camera.

``mujoco.Renderer`` renders one image per call and copies and flips it; an env step renders a frame per world, so
this class keeps the per-frame path to the three MuJoCo calls (update the scene, draw, read the pixels) and flips
the whole batch once.  Creating the GL context is the expensive part (~150 ms): build one per simulator, never on
reset.

A renderer made with ``threaded=True`` keeps its GL context current on a thread of its own for its whole life:
:meth:`BatchRenderer.submit` starts the frames there and returns at once, and :meth:`RenderJob.result` collects
them.  MuJoCo's drawing calls release the GIL, so the simulator reads its other sensors and advances the EVs on
one core while the frames are drawn on another.  The caller must not change the worlds' ``MjData`` in between.
Simulators use it only when asked (``render_thread=True`` or ``EVAAA_RENDER_THREAD=1``): between the calls of each
frame the render thread must take the GIL back, and on a 2-core machine that ate what the overlap gained.
"""

from __future__ import annotations

import os
import queue
import sys
import threading
from concurrent.futures import Future

import mujoco
import numpy as np

#: While frames are drawn on a render thread, the other threads give the GIL up after this long (seconds) when the
#: render thread asks for it between two MuJoCo calls; Python's default, 5 ms, would stall the render thread.
RENDER_SWITCH_INTERVAL = 2e-5


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


def render_thread_default() -> bool:
    """Whether simulators draw their frames on a thread of their own unless told: the environment variable
    ``EVAAA_RENDER_THREAD`` (0 or 1), off when unset.  Off by default because on the 2-core machine this project is
    measured on the thread did not pay: ``bench_env.py`` put a batch of eight worlds within a few percent either way
    of drawing in the calling thread, and a single world ~15 % slower (the GIL is taken back between the MuJoCo
    calls of every frame, so little of the other work overlaps the drawing)."""
    setting = os.environ.get("EVAAA_RENDER_THREAD", "").strip().lower()
    if setting in ("", "0", "false", "no", "off"):
        return False
    if setting in ("1", "true", "yes", "on"):
        return True
    raise ValueError(f"EVAAA_RENDER_THREAD must be 0 or 1 (unset: 0), got {setting!r}")


# the GL context made current last in each thread (making one current costs ~20 us)
_current = threading.local()

# renders in flight on render threads, and the switch interval to restore when none is
_inflight = 0
_inflight_lock = threading.Lock()
_saved_switch_interval = 0.005


def _render_started() -> None:
    global _inflight, _saved_switch_interval
    with _inflight_lock:
        if _inflight == 0:
            _saved_switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(min(_saved_switch_interval, RENDER_SWITCH_INTERVAL))
        _inflight += 1


def _render_ended() -> None:
    global _inflight
    with _inflight_lock:
        _inflight -= 1
        if _inflight == 0:
            sys.setswitchinterval(_saved_switch_interval)


class _RenderThread:
    """One thread that runs the calls given to :meth:`submit` in order (a renderer's GL context stays current in
    it).  Not a ``ThreadPoolExecutor``: its worker quits when the executor is garbage, which a renderer freed by
    the garbage collector would wait for forever."""

    def __init__(self):
        self._calls: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._serve, name="evaaa-render", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while (call := self._calls.get()) is not None:
            future, fn, args = call
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(*args))
                except BaseException as exc:  # noqa: BLE001 - handed to the caller
                    future.set_exception(exc)

    def submit(self, fn, *args) -> Future:
        future: Future = Future()
        self._calls.put((future, fn, args))
        return future

    def run(self, fn, *args):
        """``fn(*args)`` on the thread, waited for (run directly when called from the thread itself)."""
        if threading.current_thread() is self._thread:
            return fn(*args)
        return self.submit(fn, *args).result()

    @property
    def alive(self) -> bool:
        # once the interpreter is finalizing, a daemon thread no longer runs anything
        return self._thread.is_alive() and not sys.is_finalizing()

    def stop(self) -> None:
        self._calls.put(None)
        if threading.current_thread() is not self._thread:
            self._thread.join()


class RenderJob:
    """Frames being drawn (or already drawn) for :meth:`BatchRenderer.submit`; :meth:`result` returns them."""

    def __init__(self, frames: np.ndarray | None = None, future: Future | None = None):
        self._frames, self._future = frames, future

    def result(self) -> np.ndarray:
        """The frames, (N, H, W, 3) uint8, once drawn (waits for the render thread)."""
        if self._future is not None:
            try:
                self._frames = self._future.result()
            finally:
                self._future = None
                _render_ended()
        return self._frames

    def __del__(self):
        # a job dropped unread (its step raised) still ends its render: restore the switch interval
        if getattr(self, "_future", None) is not None:
            self._future = None
            _render_ended()


class BatchRenderer:
    """Renders fixed cameras of a model for any of its ``MjData`` into (N, H, W, 3) uint8 arrays."""

    def __init__(self, model: mujoco.MjModel, height: int, width: int, hidden_groups: tuple[int, ...] = (),
                 adjust=None, threaded: bool = False):
        """``adjust(row, scene, context)``, if given, may change the scene (lights, flags) or the context (fog) of
        each frame after the scene is updated and before it is drawn: worlds that share a model can still
        differ in light.  ``threaded``: draw on a thread of this renderer's own (see the module docstring)."""
        self.model = model
        self._adjust = adjust
        self.height, self.width = height, width
        self._gl = None
        self._thread = None
        if threaded:
            self._thread = _RenderThread()
            try:
                self._thread.run(self._setup, hidden_groups)
            except BaseException:
                self._thread.stop()
                self._thread = None
                raise
        else:
            self._setup(hidden_groups)

    @property
    def threaded(self) -> bool:
        return self._thread is not None

    def _setup(self, hidden_groups: tuple[int, ...]) -> None:
        model, width, height = self.model, self.width, self.height
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
        return self.submit(datas, camera_id, out).result()

    def submit(self, datas, camera_id: int, out: np.ndarray | None = None) -> RenderJob:
        """Start drawing the frames of :meth:`render`; on a threaded renderer this returns before they are drawn,
        and ``datas`` must not change until :meth:`RenderJob.result` has returned."""
        if out is None:
            out = np.empty((len(datas), self.height, self.width, 3), dtype=np.uint8)
        if self._thread is None:
            return RenderJob(frames=self._draw(datas, camera_id, out))
        _render_started()
        try:
            return RenderJob(future=self._thread.submit(self._draw, datas, camera_id, out))
        except BaseException:
            _render_ended()
            raise

    def _draw(self, datas, camera_id: int, out: np.ndarray) -> np.ndarray:
        if getattr(_current, "context", None) is not self._gl:
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
        self._gl.make_current()
        _current.context = self._gl

    def close(self) -> None:
        thread = getattr(self, "_thread", None)
        if thread is not None:
            self._thread = None
            if thread.alive:  # else the process is exiting and takes the GL objects with it
                try:
                    thread.run(self._free)
                finally:
                    thread.stop()
        else:
            self._free()

    def _free(self) -> None:
        if getattr(self, "_gl", None) is not None:
            # free the GL objects in their own context: freeing them in whichever context is current would
            # delete another renderer's textures and buffers
            self._gl.make_current()
            self._context.free()
            self._context = None
            self._gl.free()
            self._gl = None
            _current.context = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass
