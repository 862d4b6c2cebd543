"""The interface every sensor implements, and the read-only view of the world that sensors and agents query."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:  # types only: the simulator imports the sensors, never the other way round
    from ..level import Level
    from ..physiology import PhysiologyParams
    from ..predator import Predators
    from ..worldgen import ObstaclePool, ResourcePool


@runtime_checkable
class World(Protocol):
    """What a sensor (or a scripted agent) may read of the batched world after a decision's physics.

    Arrays have the world on their first axis and are the simulator's own: readers must not write to them.
    :class:`evaaa.sim.Simulator` is the one implementation.
    """

    # the level and its fixed data
    @property
    def level(self) -> Level: ...
    @property
    def n(self) -> int: ...
    #: the level's physiology (EV bounds, decay, thermal coupling, ...)
    @property
    def params(self) -> PhysiologyParams: ...
    #: height of the body's centre (the rays' and the nose's height)
    @property
    def agent_z(self) -> float: ...
    #: the item slots' fixed data (kind, extents, heading, odour, ...), P slots
    @property
    def pool(self) -> ResourcePool: ...
    #: (P,) which item slots are food, and which water
    @property
    def res_is_food(self) -> np.ndarray: ...
    @property
    def res_is_water(self) -> np.ndarray: ...
    #: the obstacle slots' fixed data (kind, extents, heading, lift, temperature, ...), O slots
    @property
    def obstacles(self) -> ObstaclePool: ...

    # the body: (N, 2) positions, (N,) compass headings in radians, (N,) decisions taken this episode
    @property
    def pos(self) -> np.ndarray: ...
    @property
    def heading_rad(self) -> np.ndarray: ...
    @property
    def steps(self) -> np.ndarray: ...
    #: (N, 4) essential variables, ordered as evaaa.physiology.EV_NAMES
    @property
    def ev(self) -> np.ndarray: ...
    #: (N, 8) temperatures at the body's thermal sensors
    @property
    def thermal_readings(self) -> np.ndarray: ...
    # items per world: (N, P, 2) positions and (N, P) presence
    @property
    def res_xy(self) -> np.ndarray: ...
    @property
    def res_present(self) -> np.ndarray: ...
    # obstacles per world: (N, O, 2) positions and (N, O) presence
    @property
    def obs_xy(self) -> np.ndarray: ...
    @property
    def obs_present(self) -> np.ndarray: ...
    #: predators: ``k`` per world, their (N, k, 2) ``xy`` and (N, k) ``heading``
    @property
    def predators(self) -> Predators: ...

    def item_distances2(self) -> np.ndarray:
        """(N, P) squared floor distances from each body's centre to each item's."""
        ...

    def can_eat(self, world: int, slot: int, pos: np.ndarray, heading: Any) -> np.ndarray:
        """Whether a body at ``pos`` facing ``heading`` would reach item ``slot`` of ``world`` with its mouth."""
        ...

    def obstacle_slices(self, world: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Floor rectangles of what blocks a body in ``world``: centres (K, 2), half-sides (K, 2), headings (K,)."""
        ...

    def ground_temperature(self, world: int, xy: np.ndarray) -> np.ndarray:
        """The floor's temperature in ``world`` under points ``xy`` (..., 2)."""
        ...

    def is_night(self) -> np.ndarray:
        """(N,) whether it is night as predators see it."""
        ...

    def render_eye(self, worlds: np.ndarray) -> np.ndarray:
        """(len(worlds), H, W, 3) uint8 frames from the agents' eyes."""
        ...


#: Every defined sensor class by its observation key (filled as sensor classes are defined).
REGISTRY: dict[str, type[Sensor]] = {}


class Sensor:
    """A modality: an observation key, its per-world shape and dtype, and how to read it.

    ``read`` returns a fresh array of shape ``(len(worlds), *shape)`` for the given world indices, from the
    world's state after the physics of the current decision (through :class:`World` only).
    """

    key: str = ""
    #: where the key comes in the canonical order of the observation keys (ties: by key)
    order: int = 100
    dtype = np.float32
    #: (low, high) every reading lies in, declared in the observation specs; None: unbounded
    bounds: tuple[float, float] | None = None

    def __init_subclass__(cls, **kwargs):
        # defining a sensor registers it: a new modality is one module (evaaa.sensors imports every module of its
        # package), or one class anywhere for a sensor of the user's own, asked for by name in ``modalities=``
        super().__init_subclass__(**kwargs)
        if not cls.key:
            return
        known = REGISTRY.get(cls.key)
        if known is not None and (known.__module__, known.__qualname__) != (cls.__module__, cls.__qualname__):
            raise ValueError(
                f"sensor key {cls.key!r} is already taken by {known.__module__}.{known.__qualname__}; "
                f"give {cls.__module__}.{cls.__qualname__} another key"
            )
        REGISTRY[cls.key] = cls

    def __init__(self, sim: World):
        self.sim = sim

    @property
    def shape(self) -> tuple[int, ...]:
        raise NotImplementedError

    def read(self, worlds: np.ndarray) -> np.ndarray:
        raise NotImplementedError
