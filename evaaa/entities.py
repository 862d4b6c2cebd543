"""Entity kinds: what each kind of thing in the world looks like, how big it is, and how it behaves.

Levels are data and say how many of which kind go where; the kinds themselves are code, here.  Extents are
(width x, depth y, height z) in metres at scale 1; a level's scale multiplies them axis by axis.  Shapes are
MuJoCo primitives; a ``dome`` is an ellipsoid centred on the floor, so only its upper half shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Kind:
    name: str
    shape: str  # box, ellipsoid, dome, cylinder
    base: tuple[float, float, float]  # extents at scale 1
    rgba: tuple[float, float, float, float]
    #: the agent's body collides with it (and rays see it as solid)
    solid: bool
    #: odour per item, five food channels then five water channels (divided by distance)
    odour: tuple[float, ...] = (0.0,) * 10
    #: footprint used for heat and for placement checks, as a fraction of the extents (the original's bonfire
    #: heats the cells under its first, box-shaped collider)
    footprint: tuple[float, float] = (1.0, 1.0)


FOOD_ODOUR = (0.1,) * 5 + (0.0,) * 5
WATER_ODOUR = (0.0,) * 5 + (0.1,) * 5

RESOURCE_KINDS: dict[str, Kind] = {
    "food": Kind("food", "box", (1.0, 1.0, 1.0), (0.85, 0.08, 0.08, 1.0), False, FOOD_ODOUR),
    "water": Kind("water", "box", (1.0, 1.0, 1.0), (0.1, 0.25, 0.95, 1.0), False, WATER_ODOUR),
    # apples smell like food cubes (the original put them on a layer its nose never queried)
    "apple": Kind("apple", "box", (1.0, 1.0, 1.0), (0.75, 0.1, 0.12, 1.0), False, FOOD_ODOUR),
    # a pond never depletes and smells a hundred times stronger than a water cube
    "pond": Kind("pond", "box", (1.0, 1.0, 1.0), (0.15, 0.4, 0.85, 1.0), True, (0.0,) * 5 + (10.0,) * 5),
}
#: EV an item of each kind feeds: 0 satiation, 1 hydration
FEEDS = {"food": 0, "apple": 0, "water": 1, "pond": 1}

OBSTACLE_KINDS: dict[str, Kind] = {
    "block": Kind("block", "box", (1.0, 1.0, 1.0), (0.7, 0.7, 0.72, 1.0), True),
    "bush": Kind("bush", "ellipsoid", (0.72, 0.73, 1.43), (0.2, 0.45, 0.15, 1.0), True),
    "rock": Kind("rock", "dome", (3.8, 3.5, 2.0), (0.45, 0.44, 0.42, 1.0), True),
    "bonfire": Kind(
        "bonfire", "cylinder", (1.5, 1.5, 0.63), (0.95, 0.42, 0.08, 1.0), True, footprint=(1.48 / 1.5, 1.0)
    ),
    "tree": Kind("tree", "box", (0.48, 0.49, 14.45), (0.4, 0.26, 0.13, 1.0), True),
    "rockwall": Kind("rockwall", "box", (0.1198, 0.016, 0.0369), (0.52, 0.48, 0.42, 1.0), True),
}
#: trees carry a canopy (seen, never touched): radius and height as fractions of the trunk's height
CANOPY = {"radius": 0.16, "height": 0.82, "rgba": (0.16, 0.38, 0.12, 1.0)}

PREDATOR = Kind("predator", "box", (1.6, 1.6, 2.0), (0.16, 0.12, 0.12, 1.0), True)


def centre_z(kind: Kind, extents: np.ndarray) -> np.ndarray:
    """Height of the centre of things of ``kind`` with ``extents`` (..., 3) resting on the floor."""
    if kind.shape == "dome":
        return np.zeros(extents.shape[:-1])
    return extents[..., 2] / 2


def footprint_half(kind: Kind, extents: np.ndarray, heading_rad: np.ndarray) -> np.ndarray:
    """Half-sides (..., 2) of the axis-aligned box around the turned footprint."""
    hw = extents[..., 0] * kind.footprint[0] / 2
    hd = extents[..., 1] * kind.footprint[1] / 2
    c, s = np.abs(np.cos(heading_rad)), np.abs(np.sin(heading_rad))
    return np.stack([hw * c + hd * s, hw * s + hd * c], axis=-1)


RECT, ELLIPSE = 0, 1


def cross_section(kind: Kind, extents: np.ndarray, height: float) -> tuple[int, np.ndarray]:
    """The horizontal slice of things of ``kind`` (resting on the floor) at ``height``: a shape (RECT or
    ELLIPSE, in the thing's own frame) and its half-axes (..., 2), zero where the slice misses the thing."""
    extents = np.asarray(extents, dtype=np.float64)
    half = extents[..., :2] / 2
    z = centre_z(kind, extents)
    if kind.shape in ("box", "cylinder"):
        inside = np.abs(height - z) <= extents[..., 2] / 2
        if kind.shape == "cylinder":
            half = np.repeat(half.max(axis=-1, keepdims=True), 2, axis=-1)
        return (RECT if kind.shape == "box" else ELLIPSE), half * inside[..., None]
    rz = extents[..., 2] if kind.shape == "dome" else extents[..., 2] / 2
    scale = np.sqrt(np.clip(1.0 - ((height - z) / rz) ** 2, 0.0, None))
    return ELLIPSE, half * scale[..., None]
