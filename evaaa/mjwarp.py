"""The MuJoCo Warp backend: every world's physics and camera at once on one device (``backend="warp"``).

:class:`WarpSimulator` is a :class:`~evaaa.sim.Simulator` whose physics substeps and egocentric frames run through
MuJoCo Warp (``mujoco-warp``, on NVIDIA Warp) over all worlds in one batch: one device model, one device data of N
worlds, five ``step`` calls per decision, one batched ray-traced render.  The game logic (items, obstacles,
triggers, predators, physiology, the other senses) is the CPU backend's, vectorised over worlds in numpy; each
world keeps its host ``MjData``, which the game logic writes (mocap bodies, the body's pose and velocity) and which
is synchronised with the device twice a decision: before the physics (every world's pose and velocity, and the
mocap bodies of the worlds whose items, obstacles or predators were written, up; pose and velocity back down) and
before the render (what the game logic changed since, up).  Frames stay on the device as a torch ``uint8`` tensor
(N, H, W, 3), so a learner on the same GPU never copies pixels; on Warp's CPU device they are CPU tensors.

What differs from the CPU backend, and only this (docs/backends.md gives the numbers):

- float32 physics and MuJoCo Warp's own contact pipeline (its collision functions, CCD for box-cylinder and
  box-ellipsoid, its Newton solver); without contacts a decision's pose agrees with ``mj_step`` to ~1e-6.
- Collision damage is computed on the device from the contact forces of each substep, through the same rule.
- Frames are ray traced (per pixel lighting) rather than rasterised by OpenGL; the day/night light is per world
  (the sun's direction and strength, the head light's dimming) and night's fog, far plane and black sky are a
  post-process on the ray depth.

Warp compiles its kernels the first time they run (minutes on a CPU) and keeps them in a cache:
:func:`kernel_cache_dir` says where.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np
import torch

from .daynight import _NIGHT_FOG, darkness, hour, original_darkness, sun
from .scene import GROUP_FLOOR, GROUP_RESOURCE, GROUP_SOLID, build_mjcf
from .sim import SUBSTEPS, Simulator

#: the optional dependencies of this backend, installed by ``pip install 'evaaa[warp]'``
EXTRA = "warp"
INSTALL_HINT = (
    "backend='warp' needs the optional packages mujoco-warp and warp-lang: "
    "pip install -c constraints.txt -e '.[warp]' (from a checkout), or pip install 'evaaa[warp]'"
)

_warp = None  # the warp module, once initialised


def kernel_cache_dir() -> Path:
    """Where Warp keeps its compiled kernels for evaaa: ``EVAAA_WARP_CACHE`` when set, else ``WARP_CACHE_PATH`` when
    set, else ``~/.cache/evaaa-warp`` (Warp adds a folder per Warp version).  Keep it between runs: a cold cache
    costs minutes of compiling on the first step."""
    for var in ("EVAAA_WARP_CACHE", "WARP_CACHE_PATH"):
        if os.environ.get(var, "").strip():
            return Path(os.environ[var]).expanduser()
    return Path("~/.cache/evaaa-warp").expanduser()


def available() -> bool:
    """Whether the packages of this backend are installed (nothing is imported)."""
    import importlib.util

    return all(importlib.util.find_spec(name) is not None for name in ("warp", "mujoco_warp"))


def load_warp():
    """``(warp, mujoco_warp)``, Warp initialised with evaaa's kernel cache; a clear error when they are missing."""
    global _warp
    try:
        import mujoco_warp as mjw
        import warp as wp
    except ImportError as exc:
        raise ImportError(f"{INSTALL_HINT} ({exc})") from None
    if _warp is None:
        wp.config.quiet = True
        if wp.config.kernel_cache_dir is None:  # not chosen by the program (nor Warp initialised before)
            wp.config.kernel_cache_dir = str(kernel_cache_dir())
        wp.init()
        _warp = wp
    return wp, mjw


def default_device() -> str:
    """Warp's device for the backend: the first CUDA GPU when Warp and torch (a CUDA build) both see one, else the
    CPU."""
    wp, _ = load_warp()
    return "cuda:0" if wp.is_cuda_available() and torch.cuda.is_available() else "cpu"


def buffer_sizes(model: mujoco.MjModel) -> tuple[int, int]:
    """Contacts and constraint rows to allocate per world, from the level's scene: the body (a box) meets at most
    a few solid bodies at once (two walls and an obstacle in a corner), each box-box pair with up to 8 contact
    points; every contact takes 4 rows of the pyramidal cone, and the two sliding joints' friction losses one each."""
    solid = int(((model.geom_contype != 0) | (model.geom_conaffinity != 0)).sum())
    nconmax = 8 * min(max(solid - 1, 1), 6)
    friction_rows = int((model.dof_frictionloss > 0).sum())
    return nconmax, 4 * nconmax + friction_rows


def _contact_damage(impulse: torch.Tensor, constant, rate, offset, cap) -> torch.Tensor:
    """:func:`evaaa.physiology.contact_damage` over a tensor of impulses."""
    if constant <= 0.0 or cap <= 0.0:
        return torch.zeros_like(impulse)
    exponent = torch.clamp(rate * (impulse - offset), max=math.log(cap / constant))
    return torch.clamp(constant * torch.exp(exponent), max=cap)


class WarpSimulator(Simulator):
    """A :class:`~evaaa.sim.Simulator` whose physics and camera run on MuJoCo Warp (see the module docstring).

    Same arguments as :class:`~evaaa.sim.Simulator`, plus ``device`` (Warp's: ``"cpu"``, ``"cuda:0"``; None: the
    first GPU, else the CPU).  ``threads`` is ignored: the device steps every world at once.  Observations are
    numpy arrays like the CPU backend's, but for ``pixels``: a torch ``uint8`` tensor on ``device``.
    """

    backend = "warp"

    def __init__(self, level, num_worlds=1, modalities=None, seed=None, threads=None, worlds="train", device=None):
        self.wp, self.mjw = load_warp()
        self.device = device or default_device()
        self._dev = None  # the device model, data and render context, made on first use
        self._moved = self._posed = None  # which worlds to send to the device (None: all)
        super().__init__(level, num_worlds, modalities, seed=seed, threads=1, worlds=worlds)
        self._setup_device()
        self._track_writes()

    # ------------------------------------------------------------------------------------------------ set-up
    def _setup_device(self) -> None:
        if self._dev is not None:
            return
        wp, mjw = self.wp, self.mjw
        n, level = self.n, self.level
        # the device's model: the host model's scene with the headlight as a model light, dimmed per world
        mjm = mujoco.MjModel.from_xml_string(build_mjcf(level, self.pool, self.obstacles, head_light=True))
        self.device_model_host = mjm
        self._head_light = mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_LIGHT, "head")
        self._sun_light = mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_LIGHT, "sun")
        nconmax, njmax = buffer_sizes(mjm)
        self.nconmax, self.njmax = nconmax, njmax
        per_world = {"light_diffuse": n, "light_ambient": n} if self.daynight.enabled else None
        with wp.ScopedDevice(self.device):
            m = mjw.put_model(mjm, batch_sizes=per_world)
            d = mjw.make_data(mjm, nworld=n, nconmax=nconmax, njmax=njmax)
            self._cids = wp.array(np.arange(d.naconmax, dtype=np.int32), dtype=int)
            self._force = wp.zeros(d.naconmax, dtype=wp.spatial_vector)
        self.m, self.d = m, d
        t = wp.to_torch
        self._t = {
            "qpos": t(d.qpos),
            "qvel": t(d.qvel),
            "qacc_warmstart": t(d.qacc_warmstart),
            "mocap_pos": t(d.mocap_pos),
            "mocap_quat": t(d.mocap_quat),
            "light_xdir": t(d.light_xdir),
            "nacon": t(d.nacon),
            "geom": t(d.contact.geom),
            "worldid": t(d.contact.worldid),
            "force": t(self._force),
        }
        tdev = self._t["qpos"].device
        self.torch_device = tdev
        self._predator_mocap = torch.as_tensor(self.index.predator_mocap, device=tdev)
        self._geom_body = torch.as_tensor(mjm.geom_bodyid, dtype=torch.int64, device=tdev)
        self._nbody = mjm.nbody
        self._dt = float(mjm.opt.timestep)
        self._overflow_warned = False
        #: seconds spent so far in the host-device exchanges (``sync``), the physics substeps with their contact
        #: damage (``physics``) and the frames (``camera``); with ``wait_for_device`` the camera's are waited for
        #: (for measurements: ``scripts/bench_env.py backend=warp``), else they may run on after the call returns
        self.seconds = {"sync": 0.0, "physics": 0.0, "camera": 0.0}
        self.wait_for_device = False
        if self.daynight.enabled:
            self._t["light_diffuse"] = t(m.light_diffuse)
            self._t["light_ambient"] = t(m.light_ambient)
        self._dev = True

    def _make_renderer(self) -> None:
        """The batched ray-traced camera of the eye (64 x 64 or the level's size), with its depth for the fog."""
        self._setup_device()
        wp, mjw = self.wp, self.mjw
        v = self.level.sensors.vision
        mjm = self.device_model_host
        with wp.ScopedDevice(self.device):
            self._rc = mjw.create_render_context(
                mjm,
                nworld=self.n,
                cam_res=(v.width, v.height),
                render_rgb=True,
                render_depth=True,
                cam_active=["eye"],
                render_skybox=True,
                use_shadows=False,
                # what the CPU backend's eye sees: MuJoCo's default groups (the agent's own group 3 hidden)
                enabled_geom_groups=[GROUP_SOLID, GROUP_RESOURCE, GROUP_FLOOR],
            )
        self._rgb = wp.to_torch(self._rc.rgb_data)
        self._depth = wp.to_torch(self._rc.depth_data)
        self._renderer = self._rc  # marks the camera as made (Simulator.render_eye's test)
        # OpenGL draws nothing nearer than the near plane nor past the far plane (without a day/night cycle)
        extent = float(mjm.stat.extent)
        self._near = float(mjm.vis.map.znear) * extent
        self._far = float(mjm.vis.map.zfar) * extent
        self._fog_rgb = torch.as_tensor(np.array(_NIGHT_FOG[:3]) * 255.0, dtype=torch.float32, device=self.torch_device)
        self._sky = self._sky_frame()

    def _sky_frame(self) -> torch.Tensor:
        """The skybox as the eye sees it, (H*W, 3): drawn once from far outside the arena, facing away from it.  The
        gradient sky depends on the height of the view only, not on the heading (they differ by < 0.2/255)."""
        data = self.datas[0]
        saved = data.qpos.copy()
        data.qpos[:3] = (0.0, -1e5, -math.pi / 2)  # heading 180: south, away from the arena
        try:
            if self._posed is not None:
                self._posed[0] = True
            rgb = self._draw()[0].float()
        finally:
            data.qpos[:] = saved
            if self._posed is not None:
                self._posed[0] = True  # the next push brings the body back
        return rgb

    # ------------------------------------------------------------------------------------------------ sync
    def _push(self, all_poses: bool) -> None:
        """The host ``MjData`` to the device: pose and velocity (of every world, or of those the game logic moved
        since the last push), and the mocap bodies of the worlds whose items, obstacles or predators were written."""
        datas, t, n = self.datas, self._t, self.n
        dev = self.torch_device
        posed = np.arange(n) if all_poses or self._posed is None else np.flatnonzero(self._posed)
        moved = np.arange(n) if self._moved is None else np.flatnonzero(self._moved)
        if len(posed) == n:
            t["qpos"].copy_(torch.from_numpy(np.stack([data.qpos for data in datas])).to(dev, torch.float32))
            t["qvel"].copy_(torch.from_numpy(np.stack([data.qvel for data in datas])).to(dev, torch.float32))
        elif len(posed):
            rows = torch.from_numpy(posed).to(dev)
            t["qpos"][rows] = torch.from_numpy(np.stack([datas[w].qpos for w in posed])).to(dev, torch.float32)
            t["qvel"][rows] = torch.from_numpy(np.stack([datas[w].qvel for w in posed])).to(dev, torch.float32)
        if self.model.nmocap and len(moved):
            pos = torch.from_numpy(np.stack([datas[w].mocap_pos for w in moved])).to(dev, torch.float32)
            quat = torch.from_numpy(np.stack([datas[w].mocap_quat for w in moved])).to(dev, torch.float32)
            if len(moved) == n:
                t["mocap_pos"].copy_(pos)
                t["mocap_quat"].copy_(quat)
            else:
                rows = torch.from_numpy(moved).to(dev)
                t["mocap_pos"][rows] = pos
                t["mocap_quat"][rows] = quat
        if self.predators.k:  # the predators of every world, from their arrays (the host MjData's may be stale)
            pose = torch.from_numpy(self.predators.poses()).to(dev, torch.float32)
            t["mocap_pos"][:, self._predator_mocap] = pose[..., :3]
            t["mocap_quat"][:, self._predator_mocap] = pose[..., 3:]
        if self._moved is not None:
            self._moved[:] = False
            self._posed[:] = False

    def _track_writes(self) -> None:
        """Note which worlds the game logic changes on the host, so that only those are sent to the device."""
        self._moved = np.ones(self.n, dtype=bool)  # mocap bodies written since the last push
        self._posed = np.ones(self.n, dtype=bool)  # pose or velocity set since the last push (besides the actions)
        moved = self._moved
        write_items, write_obstacles = self.resources.write, self.obstacle_layout.write

        def items(state, w, data):
            write_items(state, w, data)
            moved[w] = True

        def obstacles(state, w, data):
            write_obstacles(state, w, data)
            moved[w] = True

        self.resources.write, self.obstacle_layout.write = items, obstacles

    def _pull(self) -> None:
        """Pose and velocity of every world from the device into its host ``MjData`` and the state."""
        qpos = self._t["qpos"].cpu().numpy().astype(np.float64)
        qvel = self._t["qvel"].cpu().numpy().astype(np.float64)
        for w, data in enumerate(self.datas):
            data.qpos[:] = qpos[w]
            data.qvel[:] = qvel[w]
        self.state.pos[:] = qpos[:, :2]

    def _reset_world(self, w: int) -> None:
        super()._reset_world(w)
        self._posed[w] = True
        self._t["qacc_warmstart"][w] = 0.0  # a new episode starts the solver afresh, as mj_resetData does on the CPU

    def set_agent_pose(self, world: int, xy, heading_deg: float) -> None:
        self._posed[world] = True
        super().set_agent_pose(world, xy, heading_deg)

    # ------------------------------------------------------------------------------------------------ physics
    def _physics(self, worlds, damage: np.ndarray, collided: np.ndarray) -> None:
        """2. Five substeps of every world on the device; contact damage from each substep's contact forces."""
        wp, mjw, m, d = self.wp, self.mjw, self.m, self.d
        start = time.perf_counter()
        self._push(all_poses=True)  # the actions set every pose and velocity
        pushed = time.perf_counter()
        n = self.n
        dev = self.torch_device
        total = torch.zeros(n, dtype=torch.float64, device=dev)
        hit = torch.zeros(n, dtype=torch.bool, device=dev)
        with wp.ScopedDevice(self.device):
            for _ in range(SUBSTEPS):
                mjw.step(m, d)
                self._add_contact_damage(total, hit)
        damage += total.cpu().numpy()
        collided |= hit.cpu().numpy()
        stepped = time.perf_counter()
        if not self._overflow_warned and int(self._t["nacon"][0]) >= d.naconmax:
            self._overflow_warned = True
            warnings.warn(
                f"MuJoCo Warp's contact buffer ({d.naconmax} for {n} worlds) was full: contacts may have been dropped",
                stacklevel=2,
            )
        self._pull()
        self.seconds["sync"] += pushed - start + time.perf_counter() - stepped
        self.seconds["physics"] += stepped - pushed

    def _add_contact_damage(self, total: torch.Tensor, hit: torch.Tensor) -> None:
        """One substep's collision damage (the CPU backend's :class:`~evaaa.contact.ContactDamage`): the contact
        forces on the body summed per touching body, as impulses through the level's damage rule."""
        t = self._t
        k = min(int(t["nacon"][0]), self.d.naconmax)  # contacts of all worlds this substep (one wait for the device)
        if not k:
            return
        self.mjw.contact_force(self.m, self.d, self._cids[:k], True, self._force[:k])
        geom = t["geom"][:k].long()
        agent = self.index.agent_geom
        first, second = geom[:, 0] == agent, geom[:, 1] == agent
        valid = first | second
        other = torch.where(first, geom[:, 1], geom[:, 0])[valid]
        if not len(other):
            return
        world = t["worldid"][:k][valid].long()
        nbody = self._nbody
        touched, which = torch.unique(world * nbody + self._geom_body[other], return_inverse=True)
        summed = torch.zeros((len(touched), 3), dtype=torch.float64, device=total.device)
        summed.index_add_(0, which, t["force"][:k, :3][valid].double())
        constant, rate, offset, cap, threshold = self.contact.rule
        impulse = torch.linalg.vector_norm(summed, dim=1) * self._dt
        dmg = _contact_damage(impulse, constant, rate, offset, cap)
        owner = touched // nbody
        total.index_add_(0, owner, dmg)
        hits = torch.zeros_like(total).index_add_(0, owner, (dmg > threshold).double())
        hit |= hits > 0

    def _predators_act(self) -> np.ndarray:
        """4. As on the CPU, without writing the host scenes: the next push sends every world's predators from
        their arrays, and the device computes the kinematics before drawing."""
        attack = self.predators.step(self.state.pos, self.is_night(), self.rngs)
        self.state.attacked = attack != 0
        return attack

    def _write_predators(self, worlds) -> None:
        """The predators of ``worlds`` into their host ``MjData`` (which the decisions leave behind)."""
        for w in worlds:
            self.predators.write(w, self.datas[w], self.index.predator_mocap)

    # ------------------------------------------------------------------------------------------------ camera
    def render_eye(self, worlds: np.ndarray, before_draw=None) -> torch.Tensor:
        """The agent's view in ``worlds``, (len(worlds), H, W, 3) ``uint8`` on the device (drawn for every world)."""
        if self._renderer is None:
            self._make_renderer()
        start = time.perf_counter()
        frames = self._finish(self._draw()).view(self.n, *self._frame_shape)
        if self.wait_for_device:
            self.wp.synchronize_device(self.device)
            if frames.is_cuda:
                torch.cuda.synchronize(frames.device)
        self.seconds["camera"] += time.perf_counter() - start
        if len(worlds) == self.n:
            return frames
        return frames[torch.as_tensor(np.asarray(worlds), device=frames.device)]

    @property
    def _frame_shape(self) -> tuple[int, int, int]:
        v = self.level.sensors.vision
        return (v.height, v.width, 3)

    def _draw(self) -> torch.Tensor:
        """Ray trace every world's eye from the host state; (N, H*W, 3) ``uint8`` colours, depth in ``self._depth``."""
        wp, mjw, m, d, rc = self.wp, self.mjw, self.m, self.d, self._rc
        self._push(all_poses=False)
        with wp.ScopedDevice(self.device):
            mjw.kinematics(m, d)
            mjw.camlight(m, d)
            if self.daynight.enabled:
                self._light(self.state.sun_angle)
            mjw.refit_bvh(m, d, rc)
            mjw.render(m, d, rc)
        # (N, H*W) 0xAARRGGBB words: bytes B, G, R, A in memory (little-endian, as on every device Warp runs on)
        packed = self._rgb if self._rgb.dtype == torch.int32 else self._rgb.view(torch.int32)
        return packed.view(torch.uint8).view(self.n, -1, 4)[..., [2, 1, 0]]

    def _finish(self, rgb: torch.Tensor) -> torch.Tensor:
        """What OpenGL's frames have that ray tracing lacks, as ``uint8``: nothing drawn nearer than the near plane
        nor past the far plane (the sky shows there), and by night the fog, the nearer far plane and the black sky
        (:meth:`_night`)."""
        if self.daynight.enabled:
            return self._night(rgb).to(torch.uint8)
        z = self._depth  # (N, H*W) depth along the eye's axis (0: nothing hit)
        clipped = (z > 0) & ((z < self._near) | (z >= self._far))
        return torch.where(clipped[..., None], self._sky.to(rgb.dtype), rgb).to(torch.uint8)

    def _light(self, angle: np.ndarray) -> None:
        """Each world's sun (direction, strength) and head light (dimmed by the dark), as the CPU's
        :meth:`~evaaa.daynight.DayNight.light_world` sets them."""
        t, dev = self._t, self.torch_device
        dark = darkness(hour(angle))
        direction, strength = sun(angle)
        head = 1.0 - 0.8 * dark
        ones = np.ones(3)
        t["light_xdir"][:, self._sun_light] = torch.as_tensor(direction, dtype=torch.float32, device=dev)
        diffuse = t["light_diffuse"]
        ambient = t["light_ambient"]
        diffuse[:, self._sun_light] = torch.as_tensor((0.6 * strength)[:, None] * ones, dtype=torch.float32, device=dev)
        diffuse[:, self._head_light] = torch.as_tensor((0.3 * head)[:, None] * ones, dtype=torch.float32, device=dev)
        ambient[:, self._head_light] = torch.as_tensor((0.35 * head)[:, None] * ones, dtype=torch.float32, device=dev)
        dn = self.daynight.spec
        haze = original_darkness(hour(angle)) if dn.fog_schedule == "original" else dark
        density = dn.night_fog_density * haze
        fog_end = np.where(density > 0, np.sqrt(3.0) / np.maximum(density, 1e-9), 0.0)
        far = dn.day_far + (dn.night_far - dn.day_far) * haze
        self._plan = {
            "sky": torch.as_tensor(dark < 0.5, device=dev),
            "fog_end": torch.as_tensor(fog_end, dtype=torch.float32, device=dev),
            "far": torch.as_tensor(far, dtype=torch.float32, device=dev),
        }

    def _night(self, rgb: torch.Tensor) -> torch.Tensor:
        """The night on ray-traced frames: past the far plane the sky (black once the skybox is off), and linear
        fog from the eye to ``fog_end`` on what is nearer, by each pixel's depth.  (OpenGL computes the fog at the
        vertices of the coarse geometry and interpolates it, so its fog on a large face near the eye is denser:
        the main part of the difference at dusk and dawn, docs/backends.md.)"""
        plan = self._plan
        z = self._depth  # (N, H*W) depth along the eye's axis (0: nothing hit)
        hit = (z >= self._near) & (z < plan["far"][:, None])
        color = torch.where(hit[..., None], rgb.float(), self._sky)  # the skybox wherever nothing is drawn
        fog_end = plan["fog_end"][:, None]
        inverse_end = torch.where(fog_end > 0, 1.0 / torch.clamp(fog_end, min=1e-6), 0.0)
        # linear fog by the depth along the eye's axis; OpenGL draws the skybox at the far plane, fogged there
        sky_fog = torch.clamp(plan["far"][:, None] * inverse_end, 0.0, 1.0)
        fog = torch.where(hit, torch.clamp(z * inverse_end, 0.0, 1.0), sky_fog)
        fogged = color * (1 - fog[..., None]) + self._fog_rgb * fog[..., None]
        # once the skybox is off, black where nothing is drawn
        sky = plan["sky"][:, None, None]
        out = torch.where(hit[..., None] | sky, fogged, torch.zeros_like(color))
        return torch.round(out)

    def render_top(self, world: int = 0, size: int = 512) -> np.ndarray:
        """A top-down picture of one world (OpenGL, from the host ``MjData``, as on the CPU backend)."""
        self._write_predators([world])
        mujoco.mj_kinematics(self.model, self.datas[world])
        return super().render_top(world, size)

    def physics_states(self) -> np.ndarray:
        self._write_predators(range(self.n))
        return super().physics_states()

    # ------------------------------------------------------------------------------------------------ snapshots
    def restore(self, snapshot: dict) -> None:
        super().restore(snapshot)
        self._t["qacc_warmstart"].zero_()
        self._moved[:] = True
        self._posed[:] = True

    def close(self) -> None:
        self._renderer = None  # the device's buffers go with the object
        super().close()
