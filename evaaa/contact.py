"""Collision damage: the contact impulses on the body in one physics substep, through the level's damage rule."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from . import physiology as phys
from .level import Level


class ContactDamage:
    """Per substep, the damage the body takes from what touches it, and whether a touch counts as a collision.

    Contacts with one body (an obstacle, a pond, a wall) are summed into one impulse; each body's impulse goes
    through :func:`evaaa.physiology.contact_damage`, and a body whose damage exceeds the rule's event threshold
    makes the substep a collision.
    """

    def __init__(self, level: Level, model: mujoco.MjModel, agent_geom: int):
        dmg = level.agent.collision_damage
        self.rule = (dmg.constant, dmg.rate, dmg.offset, dmg.cap, dmg.event_threshold)
        self.model = model
        self.agent_geom = agent_geom
        self.dt = float(model.opt.timestep)

    def __call__(self, data: mujoco.MjData) -> tuple[float, bool]:
        """Damage of ``data``'s current contacts, and whether one of them was a collision."""
        constant, rate, offset, cap, threshold = self.rule
        agent, model = self.agent_geom, self.model
        force = np.zeros(6)
        per_body: dict[int, np.ndarray] = {}
        for c in range(data.ncon):
            contact = data.contact[c]
            if contact.geom1 == agent:
                other = contact.geom2
            elif contact.geom2 == agent:
                other = contact.geom1
            else:
                continue
            mujoco.mj_contactForce(model, data, c, force)
            world = force[:3] @ contact.frame.reshape(3, 3)
            body = int(model.geom_bodyid[other])
            per_body[body] = per_body.get(body, 0.0) + world
        total, hit = 0.0, False
        for vec in per_body.values():
            impulse = math.sqrt(float(vec @ vec)) * self.dt  # the norm, as np.linalg.norm computes it
            d = phys.contact_damage(impulse, constant, rate, offset, cap)
            total += d
            hit |= d > threshold
        return total, hit
