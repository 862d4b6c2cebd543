"""One module per sensory modality.  Each sensor declares its observation key, shape and dtype and computes its
reading for a set of worlds, so the observation spec is the union of the enabled sensors and an ablation is a
flag (the key disappears; nothing is zeroed)."""

from __future__ import annotations

from .base import Sensor, World
from .collision import CollisionRays
from .interoception import Interoception
from .olfaction import Olfaction
from .thermoception import Thermoception
from .vision import Vision

#: Observation keys in their canonical order, and the sensor class behind each.
SENSORS: dict[str, type[Sensor]] = {
    "pixels": Vision,
    "interoception": Interoception,
    "olfaction": Olfaction,
    "thermoception": Thermoception,
    "collision": CollisionRays,
}
MODALITIES: tuple[str, ...] = tuple(SENSORS)
#: Other names accepted for a modality in ``modalities=``.
ALIASES = {"vision": "pixels", "rgb": "pixels", "ev": "interoception"}

__all__ = ["Sensor", "World", "SENSORS", "MODALITIES", "ALIASES", "resolve_modalities"]


def resolve_modalities(modalities) -> tuple[str, ...]:
    """Validate a user's ``modalities`` (None: all) and return the keys in canonical order."""
    if modalities is None:
        return MODALITIES
    if isinstance(modalities, str):
        modalities = [modalities]
    chosen = set()
    for name in modalities:
        key = ALIASES.get(name, name)
        if key not in SENSORS:
            raise ValueError(
                f"unknown modality {name!r}; allowed: {', '.join(MODALITIES)} (aliases: {', '.join(ALIASES)})"
            )
        chosen.add(key)
    if not chosen:
        raise ValueError(f"modalities must name at least one of: {', '.join(MODALITIES)}")
    return tuple(k for k in MODALITIES if k in chosen)
