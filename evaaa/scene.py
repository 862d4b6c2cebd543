"""The MuJoCo scene of a level: MJCF text, the compiled model, and the indices of its pooled bodies.

One model serves every world of a batch: per-episode entities (resources, random obstacles, predators) are
mocap bodies that are moved or parked below the floor, so a new layout never recompiles anything; static
obstacles are plain world geoms.  Render settings are chosen for a CPU: no multisampling or shadows, coarse
tessellation and a coarse floor grid (see ARCHITECTURE section 5).

Frames: x east, y north, z up; the floor's walking surface is z = 0; headings are compass angles (0 faces +y,
90 faces +x).  The agent's hinge angle is the math angle psi = 90 deg - heading; a body turned to compass
heading h is rotated by -h about z.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np

from .entities import CANOPY, OBSTACLE_KINDS, PREDATOR, RESOURCE_KINDS, Kind
from .level import Level, LevelError
from .worldgen import AGENT_HALF, PARKED_Z, ObstaclePool, ResourcePool

# Geom groups, so that cameras and rays can choose what they see.
GROUP_SOLID = 0  # walls, obstacles, ponds, predators: seen and hit by rays
GROUP_RESOURCE = 1  # consumables: seen and hit by rays, no contact with the agent
GROUP_FLOOR = 2  # seen, never hit by the horizontal rays
GROUP_AGENT = 3  # the agent's own body: hidden from its eye (MuJoCo hides groups 3-5 unless asked)
GROUP_INVISIBLE = 4  # bounds of open arenas: collide and are hit by rays, never drawn

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
    sun_light: int
    resource_mocap: np.ndarray  # (P,) mocap index of each resource slot
    obstacle_mocap: np.ndarray  # (O,) mocap index of each obstacle slot (-1 for static obstacles)
    predator_mocap: np.ndarray  # (K,) mocap index of each predator slot
    ray_groups: np.ndarray  # (6,) uint8 geom-group mask for the collision rays


def _f(x: float) -> str:
    return f"{x:.6g}"


def _v(values) -> str:
    return " ".join(_f(v) for v in values)


def _geom(kind: Kind, extents: np.ndarray, *, group: int, solid: bool, extra: str = "") -> str:
    """A geom of ``kind`` with ``extents`` centred on its body (whose origin sits at the kind's centre)."""
    w, d, h = (float(e) for e in extents)
    if kind.shape == "box":
        shape = f'type="box" size="{_v((w / 2, d / 2, h / 2))}"'
    elif kind.shape == "ellipsoid":
        shape = f'type="ellipsoid" size="{_v((w / 2, d / 2, h / 2))}"'
    elif kind.shape == "dome":
        shape = f'type="ellipsoid" size="{_v((w / 2, d / 2, h))}"'
    elif kind.shape == "cylinder":
        shape = f'type="cylinder" size="{_v((max(w, d) / 2, h / 2))}"'
    else:  # a new kind with an unknown shape is a programming error
        raise ValueError(f"unknown shape {kind.shape!r} of kind {kind.name!r}")
    contact = "" if solid else ' contype="0" conaffinity="0"'
    return f'<geom {shape} rgba="{_v(kind.rgba)}" group="{group}"{contact}{extra}/>'


def _canopy(extents: np.ndarray) -> str:
    h = float(extents[2])
    r = CANOPY["radius"] * h
    return (
        f'<geom type="ellipsoid" size="{_v((r, r, 0.6 * r))}" pos="0 0 {_f(CANOPY["height"] * h - h / 2)}" '
        f'rgba="{_v(CANOPY["rgba"])}" group="{GROUP_SOLID}" contype="0" conaffinity="0"/>'
    )


def _euler(heading_rad: float) -> str:
    return f'euler="0 0 {_f(-heading_rad)}"'


def _resources(pool: ResourcePool) -> str:
    out = []
    for j in range(pool.size_total):
        kind = RESOURCE_KINDS[pool.kind[j]]
        group = GROUP_SOLID if kind.solid else GROUP_RESOURCE
        out.append(
            f'    <body name="res{j}" mocap="true" pos="0 0 {_f(PARKED_Z)}" {_euler(pool.heading[j])}>'
            f"{_geom(kind, pool.extents[j], group=group, solid=kind.solid)}</body>"
        )
    return "\n".join(out)


def _obstacles(pool: ObstaclePool) -> str:
    out = []
    z = pool.centre_z()
    for o in range(pool.size_total):
        kind = OBSTACLE_KINDS[pool.kind[o]]
        geoms = _geom(kind, pool.extents[o], group=GROUP_SOLID, solid=True)
        if kind.name == "tree":
            geoms += _canopy(pool.extents[o])
        if pool.static[o]:  # never moves: a plain body welded to the world
            pos = (pool.low[o, 0], pool.low[o, 1], z[o])
            out.append(f'    <body name="obs{o}" pos="{_v(pos)}" {_euler(pool.heading[o])}>{geoms}</body>')
        else:
            out.append(
                f'    <body name="obs{o}" mocap="true" pos="0 0 {_f(PARKED_Z)}" '
                f"{_euler(pool.heading[o])}>{geoms}</body>"
            )
    return "\n".join(out)


def _predators(count: int) -> str:
    # predators are moved kinematically and never push the agent: contact is handled by their state machine
    return "\n".join(
        f'    <body name="pred{k}" mocap="true" pos="0 0 {_f(PARKED_Z)}">'
        f"{_geom(PREDATOR, np.array(PREDATOR.base), group=GROUP_SOLID, solid=False)}"
        f'<geom type="box" size="0.12 0.05 0.06" pos="0.45 0.81 0.55" rgba="0.9 0.15 0.1 1" group="{GROUP_SOLID}" '
        f'contype="0" conaffinity="0"/>'
        f'<geom type="box" size="0.12 0.05 0.06" pos="-0.45 0.81 0.55" rgba="0.9 0.15 0.1 1" group="{GROUP_SOLID}" '
        f'contype="0" conaffinity="0"/></body>'
        for k in range(count)
    )


def build_mjcf(
    level: Level, pool: ResourcePool, obstacles: ObstaclePool | None = None, head_light: bool = False
) -> str:
    """MJCF text of a level's scene with one pooled body per resource, obstacle and predator slot.

    ``head_light``: the headlight as a light of the model (``head``, in the agent's body, shining where the eye
    looks) instead of MuJoCo's headlight, for renderers that can dim a model light per world but not the headlight
    (the MuJoCo Warp backend, :mod:`evaaa.mjwarp`).  Same light, same frames."""
    obstacles = obstacles if obstacles is not None else ObstaclePool.from_level(level)
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
    n_predators = sum(g.count for g in level.predators.values())
    friction = a.floor_friction * a.mass * GRAVITY  # Coulomb floor friction, as a joint friction loss
    damping = a.linear_drag * a.mass  # linear drag as joint damping
    top_height = max(hx, hy) / np.tan(np.radians(45 / 2)) + 1.0
    headlight = '<headlight ambient="0.35 0.35 0.35" diffuse="0.3 0.3 0.3" specular="0 0 0"/>'
    eye_light = ""
    if head_light:
        headlight = '<headlight active="0"/>'
        eye_light = (
            '      <light name="head" directional="true" pos="0 0 0" dir="1 0 0" ambient="0.35 0.35 0.35" '
            'diffuse="0.3 0.3 0.3" specular="0 0 0" castshadow="false"/>\n'
        )
    # the name is checked at load (level.LEVEL_NAME), but a level's text is data: quoted as XML, it can never end
    # the attribute and add elements (an <include> would make MuJoCo open any file, a FIFO hang it)
    return f"""<mujoco model={quoteattr(f"evaaa-{level.name}")}>
  <compiler angle="radian"/>
  <option timestep="0.02" gravity="0 0 -{GRAVITY}"/>
  <statistic extent="1" center="0 0 0"/>
  <visual>
    <quality offsamples="0" shadowsize="0" numquads="1" numslices="8" numstacks="4"/>
    <map znear="{_f(vis.near)}" zfar="{_f(vis.far)}"/>
    {headlight}
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
{eye_light}      <camera name="eye" pos="{_f(EYE_FORWARD)} 0 {_f(EYE_HEIGHT)}" xyaxes="0 -1 0 0 0 1" fovy="{_f(vis.fovy)}"/>
    </body>
{_resources(pool)}
{_obstacles(obstacles)}
{_predators(n_predators)}
  </worldbody>
</mujoco>
"""


def _xml_culprit(message: str, pool: ResourcePool, obstacles: ObstaclePool) -> str:
    """The level field behind the MJCF element that a MuJoCo compile error names."""
    found = re.search(r"Element name '([a-z_]+?)(\d*)'", message)
    if found is None:
        return "level"
    stem, number = found.groups()
    if stem == "res" and number:
        return f"resources.{pool.names[pool.group[int(number)]]} (size)"
    if stem == "obs" and number:
        return f"obstacles.{obstacles.names[obstacles.group[int(number)]]} (scale)"
    if stem == "agent":
        return "agent.mass"
    if stem.startswith("wall") or stem == "floor":
        return "arena (size, wall_height)"
    return "predators" if stem == "pred" else "level"


def build_model(level: Level, pool: ResourcePool, obstacles: ObstaclePool) -> tuple[mujoco.MjModel, SceneIndex]:
    try:
        model = mujoco.MjModel.from_xml_string(build_mjcf(level, pool, obstacles))
    except ValueError as exc:  # MuJoCo refuses a body the level's numbers made (too light, too thin, ...)
        raise LevelError(
            f"invalid level '{level.name}':\n  {_xml_culprit(str(exc), pool, obstacles)}: MuJoCo "
            f"cannot build it: {' '.join(str(exc).split())}"
        ) from None

    def body(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)

    n_predators = sum(g.count for g in level.predators.values())
    ray_groups = np.zeros(6, dtype=np.uint8)
    ray_groups[[GROUP_SOLID, GROUP_INVISIBLE]] = 1  # consumables are ray-tested by the sensor itself
    index = SceneIndex(
        agent_body=body("agent"),
        agent_geom=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "agent"),
        eye_camera=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "eye"),
        top_camera=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "top"),
        sun_light=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_LIGHT, "sun"),
        resource_mocap=np.array([model.body_mocapid[body(f"res{j}")] for j in range(pool.size_total)], np.int64),
        obstacle_mocap=np.array([model.body_mocapid[body(f"obs{o}")] for o in range(obstacles.size_total)], np.int64),
        predator_mocap=np.array([model.body_mocapid[body(f"pred{k}")] for k in range(n_predators)], np.int64),
        ray_groups=ray_groups,
    )
    return model, index
