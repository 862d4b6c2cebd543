"""Off-screen rendering of many worlds that share one model: one GL context, one scene, one camera.

``mujoco.Renderer`` renders one image per call and copies and flips it; an env step renders a frame per world, so
this class keeps the per-frame path to the three MuJoCo calls (update the scene, draw, read the pixels) and flips
the whole batch once.  Creating the GL context is the expensive part (~150 ms): build one per simulator, never on
reset.

A renderer made with ``threaded=True`` keeps its GL context current on a thread of its own for its whole life:
:meth:`BatchRenderer.submit` starts the frames there and returns at once, and :meth:`RenderJob.result` collects
them; the caller must not change the worlds' ``MjData`` in between.  :class:`SplitRenderer` puts several such
threads to work at once, each with a GL context of its own and a contiguous share of the worlds.  MuJoCo's drawing
calls release the GIL and Mesa's software rasteriser draws a 64x64 frame on one core, so on a 2-core machine two
threads draw a batch of frames ~1.5x faster than one; the pixels are the same.  (Overlapping a render thread's
drawing with the rest of a decision, by contrast, did not pay: the Python code of the other sensors holds the GIL
that the render thread needs between its MuJoCo calls.  A single world turns it round: its frame is drawn on the
calling thread, in one long GIL-free call, while a helper thread runs that Python.)  How many threads a simulator
uses: :func:`evaaa.sim.default_threads`.
"""

from __future__ import annotations

import contextlib
import os
import queue
import sys
import threading
from concurrent.futures import Future

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


# the GL context made current last in each thread (making one current costs ~20 us)
_current = threading.local()
# the renderers' GL contexts not yet freed
_live: set = set()
# held around every draw and read-back when drawing is serial (see draw_lock)
_DRAW_LOCK = threading.Lock()


def draw_lock():
    """What a frame's draw and read-back are done under: nothing, or with ``EVAAA_SERIAL_DRAW=1`` one lock for the
    whole process.  Two training runs died in ``mjr_render`` (Mesa 22.3 llvmpipe through EGL) while two render
    threads of one process drew at once, each in its own GL context.  Taking the draws in turn avoids that, but a
    batch split in two shares then steps slower than on one thread (``scripts/bench_env.py``), so it is not the
    default: ``threads=1`` (one render thread) is the safe setting that keeps the speed of one thread.  Read when a
    renderer is made."""
    if os.environ.get("EVAAA_SERIAL_DRAW", "0") == "1":
        return _DRAW_LOCK
    return contextlib.nullcontext()


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
            future, self._future = self._future, None
            self._frames = future.result()
        return self._frames


class BatchRenderer:
    """Renders fixed cameras of a model for any of its ``MjData`` into (N, H, W, 3) uint8 arrays."""

    def __init__(
        self,
        model: mujoco.MjModel,
        height: int,
        width: int,
        hidden_groups: tuple[int, ...] = (),
        adjust=None,
        threaded: bool = False,
    ):
        """``adjust(row, scene, context)``, if given, may change the scene (lights, flags) or the context (fog) of
        each frame after the scene is updated and before it is drawn: worlds that share a model can still
        differ in light.  ``threaded``: draw on a thread of this renderer's own (see the module docstring)."""
        self.model = model
        self._adjust = adjust
        self.height, self.width = height, width
        self._gl = None
        self._thread = None
        self._lock = draw_lock()
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
            _live.add(self._gl)
            self._make_current()
            self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        except Exception as exc:  # noqa: BLE001 - every GL failure gets the same explanation
            raise gl_error(exc) from exc
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        if width > self._context.offWidth or height > self._context.offHeight:
            raise ValueError(
                f"image {width}x{height} exceeds the off-screen buffer "
                f"{self._context.offWidth}x{self._context.offHeight}"
            )
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
        self._option = mujoco.MjvOption()
        for group in hidden_groups:
            self._option.geomgroup[group] = 0
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._catmask = int(mujoco.mjtCatBit.mjCAT_ALL)
        # MuJoCo hands the context's fog settings to OpenGL only when the context is made; a frame whose
        # ``adjust`` turns fog on gets them handed over again (PyOpenGL, a MuJoCo dependency, picks the same
        # platform as the context)
        from OpenGL import GL

        self._gl_api = GL
        self._fog_flag = mujoco.mjtRndFlag.mjRND_FOG

    def render(self, datas, camera_id: int, out: np.ndarray | None = None, before_draw=None) -> np.ndarray:
        """Frames of ``camera_id`` for each data in ``datas``, upright, as (len(datas), H, W, 3) uint8.

        ``before_draw()``, if given, is called once the first frame's scene is ready, just before it is drawn:
        work started there runs while the drawing call, which frees the GIL, keeps this thread busy (not on a
        threaded renderer)."""
        if before_draw is not None and self._thread is not None:
            raise ValueError("before_draw is for renderers that draw on the calling thread")
        return self.submit(datas, camera_id, out, before_draw=before_draw).result()

    def submit(
        self, datas, camera_id: int, out: np.ndarray | None = None, first_row: int = 0, before_draw=None
    ) -> RenderJob:
        """Start drawing the frames of :meth:`render`; on a threaded renderer this returns before they are drawn,
        and ``datas`` must not change until :meth:`RenderJob.result` has returned.  ``first_row``: the row of
        ``datas[0]`` in a larger batch (what ``adjust`` is told)."""
        if out is None:
            out = np.empty((len(datas), self.height, self.width, 3), dtype=np.uint8)
        if self._thread is None:
            return RenderJob(frames=self._draw(datas, camera_id, out, first_row, before_draw))
        return RenderJob(future=self._thread.submit(self._draw, datas, camera_id, out, first_row))

    def _draw(self, datas, camera_id: int, out: np.ndarray, first_row: int = 0, before_draw=None) -> np.ndarray:
        if getattr(_current, "context", None) is not self._gl:
            self._make_current()
        self._camera.fixedcamid = camera_id
        model, scene, context, rect = self.model, self._scene, self._context, self._rect
        for row, data in enumerate(datas):
            mujoco.mjv_updateScene(model, data, self._option, None, self._camera, self._catmask, scene)
            if self._adjust is not None:
                self._adjust(first_row + row, scene, context)
                if scene.flags[self._fog_flag]:
                    self._apply_fog(context)
            if before_draw is not None:
                before_draw()
                before_draw = None
            with self._lock:
                mujoco.mjr_render(rect, scene, context)
                mujoco.mjr_readPixels(out[row], None, rect, context)
        # OpenGL rows run bottom-up
        out[:] = out[:, ::-1]
        return out

    def _apply_fog(self, context: mujoco.MjrContext) -> None:
        GL = self._gl_api
        GL.glFogf(GL.GL_FOG_START, context.fogStart)
        GL.glFogf(GL.GL_FOG_END, context.fogEnd)
        GL.glFogfv(GL.GL_FOG_COLOR, np.asarray(context.fogRGBA, dtype=np.float32))

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
        gl = getattr(self, "_gl", None)
        if gl is not None:
            # free the GL objects in their own context: freeing them in whichever context is current would
            # delete another renderer's textures and buffers
            previous = getattr(_current, "context", None)
            gl.make_current()
            self._context.free()
            self._context = None
            _live.discard(gl)
            gl.free()
            self._gl = None
            _current.context = None
            # the garbage collector frees a renderer in whichever thread it runs, perhaps in the middle of another
            # renderer's frame there: give that thread its context back, or the rest of the frame is drawn
            # without one
            if previous is not None and previous is not gl and previous in _live:
                previous.make_current()
                _current.context = previous

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


class _Jobs:
    """The parts of one :meth:`SplitRenderer.submit`, collected together."""

    def __init__(self, jobs: list[RenderJob], frames: np.ndarray):
        self._jobs, self._frames = jobs, frames

    def result(self) -> np.ndarray:
        """The frames, once every part is drawn (a part's failure is raised after all parts have ended)."""
        error = None
        for job in self._jobs:
            try:
                job.result()
            except BaseException as exc:  # noqa: BLE001 - raised once all parts have ended
                error = error or exc
        if error is not None:
            raise error
        return self._frames


class SplitRenderer:
    """A :class:`BatchRenderer` that draws a batch on ``threads`` threads at once, each with its own GL context and
    a contiguous share of the worlds (as even as the batch allows).  Same interface and frames."""

    def __init__(
        self,
        model: mujoco.MjModel,
        height: int,
        width: int,
        hidden_groups: tuple[int, ...] = (),
        adjust=None,
        threads: int = 2,
    ):
        if threads < 1:
            raise ValueError(f"SplitRenderer needs threads >= 1, got {threads}")
        self.height, self.width = height, width
        self._parts: list[BatchRenderer] = []
        try:
            for _ in range(threads):
                self._parts.append(BatchRenderer(model, height, width, hidden_groups, adjust, threaded=True))
        except BaseException:
            self.close()
            raise

    @property
    def threaded(self) -> bool:
        return True

    @property
    def threads(self) -> int:
        return len(self._parts)

    def render(self, datas, camera_id: int, out: np.ndarray | None = None) -> np.ndarray:
        return self.submit(datas, camera_id, out).result()

    def submit(self, datas, camera_id: int, out: np.ndarray | None = None) -> _Jobs:
        n = len(datas)
        if out is None:
            out = np.empty((n, self.height, self.width, 3), dtype=np.uint8)
        k = min(len(self._parts), n)
        bounds = [n * i // k for i in range(k + 1)]
        jobs = [
            part.submit(datas[a:b], camera_id, out[a:b], first_row=a)
            for part, a, b in zip(self._parts, bounds[:-1], bounds[1:])
        ]
        return _Jobs(jobs, out)

    def close(self) -> None:
        parts, self._parts = self._parts, []
        for part in parts:
            part.close()
