"""The MuJoCo scene of a level: MJCF text, the compiled model, and the indices of its pooled bodies.

One model serves every world of a batch: per-episode entities (resources) are mocap bodies that are moved or
parked below the floor, so a new layout never recompiles anything.  Render settings are chosen for a CPU:
no multisampling or shadows, coarse tessellation and a coarse floor grid (see ARCHITECTURE section 5).

Frames: x east, y north, z up; the floor's walking surface is z = 0; headings are compass angles (0 faces +y,
90 faces +x).  The agent's hinge angle is the math angle psi = 90 deg - heading.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from .spec import Level
from .worldgen import AGENT_HALF, FOOD, PARKED_Z, ResourcePool

# Geom groups, so that cameras and rays can choose what they see.
GROUP_SOLID = 0  # walls, obstacles: seen, hit by rays, collide with the agent
GROUP_RESOURCE = 1  # consumables: seen and hit by rays, no contact with the agent
GROUP_FLOOR = 2  # seen, never hit by the horizontal rays
GROUP_AGENT = 3  # the agent's own body: hidden from its eye
GROUP_INVISIBLE = 4  # bounds of open arenas: collide and are hit by rays, never drawn

#: Colours of consumables (RGBA): pure red food and blue water, as in the original.
KIND_RGBA = {FOOD: "0.85 0.08 0.08 1", 1: "0.1 0.25 0.95 1"}
FLOOR_RGB = {
    "ground": ("0.42 0.38 0.27", "0.38 0.35 0.25"),
    "gray": ("0.5 0.5 0.5", "0.46 0.46 0.46"),
}
EYE_HEIGHT = 0.0  # the eye sits at the body centre's height (0.5 m above the floor)
EYE_FORWARD = 0.249
GRAVITY = 9.81


@dataclass(frozen=True)
class SceneIndex:
    """Indices into the compiled model that the simulator needs on the hot path."""

    agent_body: int
    agent_geom: int
    eye_camera: int
    top_camera: int
    resource_mocap: np.ndarray  # (P,) mocap index of each resource slot
    ray_groups: np.ndarray  # (6,) uint8 geom-group mask for the collision rays


def _f(x: float) -> str:
    return f"{x:.6g}"


def build_mjcf(level: Level, pool: ResourcePool) -> str:
    """MJCF text of a level's scene with one mocap body per resource slot."""
    a, arena, vis = level.agent, level.arena, level.sensors.vision
    hx, hy = arena.size[0] / 2, arena.size[1] / 2
    rgb1, rgb2 = FLOOR_RGB[arena.floor]
    grid_spacing = 10.0
    wall_h = arena.wall_height
    wall_group, wall_rgba = (GROUP_SOLID, "0.62 0.6 0.56 1") if arena.walls else (GROUP_INVISIBLE, "0 0 0 0")
    walls = "\n".join(
        f'    <geom name="wall_{n}" type="box" size="{_f(sx)} {_f(sy)} {_f(wall_h / 2)}" '
        f'pos="{_f(px)} {_f(py)} {_f(wall_h / 2)}" group="{wall_group}" rgba="{wall_rgba}"/>'
        for n, (sx, sy, px, py) in {
            "e": (0.5, hy + 1, hx + 0.5, 0),
            "w": (0.5, hy + 1, -hx - 0.5, 0),
            "n": (hx + 1, 0.5, 0, hy + 0.5),
            "s": (hx + 1, 0.5, 0, -hy - 0.5),
        }.items()
    )
    resources = "\n".join(
        f'    <body name="res{j}" mocap="true" pos="0 0 {_f(PARKED_Z)}">'
        f'<geom type="box" size="{_f(s / 2)} {_f(s / 2)} {_f(s / 2)}" rgba="{KIND_RGBA[k]}" '
        f'group="{GROUP_RESOURCE}" contype="0" conaffinity="0"/></body>'
        for j, (k, s) in enumerate(zip(pool.kind, pool.size))
    )
    friction = a.floor_friction * a.mass * GRAVITY  # Coulomb floor friction, as a joint friction loss
    damping = a.linear_drag * a.mass  # linear drag as joint damping
    top_height = max(hx, hy) / np.tan(np.radians(45 / 2)) + 1.0
    return f"""<mujoco model="evaaa-{level.name}">
  <compiler angle="radian"/>
  <option timestep="0.02" gravity="0 0 -{GRAVITY}"/>
  <statistic extent="1" center="0 0 0"/>
  <visual>
    <quality offsamples="0" shadowsize="0" numquads="1" numslices="8" numstacks="4"/>
    <map znear="{_f(vis.near)}" zfar="{_f(vis.far)}"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.3 0.3 0.3" specular="0 0 0"/>
    <global offwidth="1024" offheight="1024"/>
  </visual>
  <default>
    <!-- contacts are over-damped so a hit stops the agent without bouncing it back -->
    <geom solref="0.04 2" solimp="0.95 0.99 0.001" friction="{_f(a.floor_friction)} 0.005 0.0001"/>
  </default>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.55 0.72 0.92" rgb2="0.9 0.93 0.97" width="32" height="32"/>
    <texture name="floor" type="2d" builtin="checker" rgb1="{rgb1}" rgb2="{rgb2}" width="64" height="64"/>
    <material name="floor" texture="floor" texrepeat="{_f(arena.size[0] / 10)} {_f(arena.size[1] / 10)}" specular="0"/>
  </asset>
  <worldbody>
    <light name="sun" directional="true" pos="0 0 50" dir="-0.3 0.4 -1" diffuse="0.6 0.6 0.6" specular="0 0 0" castshadow="false"/>
    <geom name="floor" type="plane" size="{_f(hx)} {_f(hy)} {_f(grid_spacing)}" material="floor" group="{GROUP_FLOOR}" contype="0" conaffinity="0"/>
{walls}
    <camera name="top" pos="0 0 {_f(top_height)}" xyaxes="1 0 0 0 1 0" fovy="45"/>
    <body name="agent" pos="0 0 {_f(AGENT_HALF)}">
      <joint name="x" type="slide" axis="1 0 0" damping="{_f(damping)}" frictionloss="{_f(friction)}"/>
      <joint name="y" type="slide" axis="0 1 0" damping="{_f(damping)}" frictionloss="{_f(friction)}"/>
      <!-- turning is set directly; the large armature keeps contact torques from spinning the body -->
      <joint name="yaw" type="hinge" axis="0 0 1" armature="1e6"/>
      <geom name="agent" type="box" size="{_f(AGENT_HALF)} {_f(AGENT_HALF)} {_f(AGENT_HALF)}" mass="{_f(a.mass)}" rgba="0.93 0.86 0.7 1" group="{GROUP_AGENT}"/>
      <geom type="box" size="0.12 0.35 0.08" pos="0.45 0 0.25" rgba="0.3 0.25 0.2 1" group="{GROUP_AGENT}" contype="0" conaffinity="0" mass="0"/>
      <camera name="eye" pos="{_f(EYE_FORWARD)} 0 {_f(EYE_HEIGHT)}" xyaxes="0 -1 0 0 0 1" fovy="{_f(vis.fovy)}"/>
    </body>
{resources}
  </worldbody>
</mujoco>
"""


def build_model(level: Level, pool: ResourcePool) -> tuple[mujoco.MjModel, SceneIndex]:
    model = mujoco.MjModel.from_xml_string(build_mjcf(level, pool))
    res_bodies = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"res{j}") for j in range(pool.size_total)]
    ray_groups = np.zeros(6, dtype=np.uint8)
    ray_groups[[GROUP_SOLID, GROUP_RESOURCE, GROUP_INVISIBLE]] = 1
    index = SceneIndex(
        agent_body=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "agent"),
        agent_geom=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "agent"),
        eye_camera=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "eye"),
        top_camera=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "top"),
        resource_mocap=np.array([model.body_mocapid[b] for b in res_bodies], dtype=np.int64),
        ray_groups=ray_groups,
    )
    return model, index
