"""One module per sensory modality.  Each sensor declares its observation key, shape and dtype and computes its
reading for a set of worlds, so the observation spec is the union of the enabled sensors and an ablation is a
flag (the key disappears; nothing is zeroed)."""

from __future__ import annotations

import importlib
import pkgutil

from .base import REGISTRY, Sensor, World

# every module of this package that defines a Sensor subclass registers it by being imported: a new modality is
# one module here (plus its level spec field if it has settings)
for _module in pkgutil.iter_modules(__path__):
    if _module.name != "base":
        importlib.import_module(f"{__name__}.{_module.name}")


def _canonical(keys) -> tuple[str, ...]:
    return tuple(sorted(keys, key=lambda k: (REGISTRY[k].order, k)))


#: The observation key -> sensor class of every sensor defined (this package's, and any a user's code defines).
SENSORS: dict[str, type[Sensor]] = REGISTRY
#: This package's observation keys in their canonical order: what an env emits by default.
MODALITIES: tuple[str, ...] = _canonical(REGISTRY)
#: Other names accepted for a modality in ``modalities=``.
ALIASES = {"vision": "pixels", "rgb": "pixels", "ev": "interoception"}

__all__ = ["Sensor", "World", "SENSORS", "MODALITIES", "ALIASES", "resolve_modalities"]


def resolve_modalities(modalities) -> tuple[str, ...]:
    """Validate a user's ``modalities`` (None: this package's, :data:`MODALITIES`) and return the keys in canonical
    order."""
    if modalities is None:
        return MODALITIES
    if isinstance(modalities, str):
        modalities = [modalities]
    chosen = set()
    for name in modalities:
        key = ALIASES.get(name, name)
        if key not in SENSORS:
            raise ValueError(
                f"unknown modality {name!r}; allowed: {', '.join(_canonical(SENSORS))} (aliases: {', '.join(ALIASES)})"
            )
        chosen.add(key)
    if not chosen:
        raise ValueError(f"modalities must name at least one of: {', '.join(MODALITIES)}")
    return _canonical(chosen)
