"""Three disjoint sets of worlds from one seed: training, validation and test.

A world is a stream of episodes drawn from its own generator.  ``make_env(seed=s)`` gives world *i* the *i*-th child
of ``SeedSequence(s)`` (spawn key ``(i,)``): the training worlds, as they have always been.  Validation and test
worlds descend from ``SeedSequence(s, spawn_key=(K,))`` with a key ``K`` of their own, so their world *i* has the
spawn key ``(K, i)``.  Spawn keys of different lengths or values never coincide, so for every pair of seeds and every
number of worlds, no validation or test world is a training world of any run, and no test world a validation world:
disjoint by construction, not by the luck of an offset.

Periodic evaluations during training, model selection and every setting anyone tunes use the validation worlds;
every published number comes from the test worlds (``scripts/evaluate.py`` defaults to them).
"""

from __future__ import annotations

import numpy as np

#: the sets of worlds a seed gives, by name
WORLD_SETS = ("train", "validation", "test")

# the first spawn-key word of each held-out set: any values would do as long as they differ from each other (the
# training worlds' keys have one word, these two); 'val' and 'test' in ASCII, for whoever meets them in a debugger
_SPAWN_KEY = {"validation": 0x76616C, "test": 0x74657374}


def check_worlds(worlds: str) -> str:
    """``worlds`` if it names a set of worlds, else a ValueError naming the allowed values."""
    if worlds not in WORLD_SETS:
        raise ValueError(f"worlds must be one of {', '.join(WORLD_SETS)}; got {worlds!r}")
    return worlds


def world_seeds(seed: int | None, worlds: str, num_worlds: int) -> list[np.random.SeedSequence]:
    """The seed sequence of each of ``num_worlds`` worlds of the set ``worlds`` of ``seed`` (None: fresh entropy)."""
    check_worlds(worlds)
    if worlds == "train":
        root = np.random.SeedSequence(seed)
    else:
        root = np.random.SeedSequence(seed, spawn_key=(_SPAWN_KEY[worlds],))
    return root.spawn(num_worlds)
