"""Training, validation and test worlds are disjoint sets, whatever the seed and the number of worlds."""

from __future__ import annotations

import numpy as np
import pytest

import evaaa
from evaaa.sim import Simulator
from evaaa.worlds import WORLD_SETS, world_seeds

SEEDS = range(100)
NUM_WORLDS = (1, 3, 8)


def _layouts(worlds: str, num_worlds: int) -> set[bytes]:
    """The first layout of every world of every seed: agent pose and item positions, as bytes."""
    sim = Simulator(evaaa.load_level("1-1"), num_worlds, ["interoception"], seed=0, worlds=worlds)
    out = set()
    try:
        for seed in SEEDS:
            sim.seed(seed)
            sim.reset()
            for w in range(num_worlds):
                items = sim.res_xy[w][sim.res_present[w]]
                out.add(np.concatenate([sim.pos[w], [sim.heading_rad[w]], items.ravel()]).round(6).tobytes())
    finally:
        sim.close()
    return out


def test_test_worlds_never_coincide_with_training_or_validation_worlds():
    layouts = {(worlds, n): _layouts(worlds, n) for worlds in WORLD_SETS for n in NUM_WORLDS}
    by_set = {worlds: set().union(*(layouts[worlds, n] for n in NUM_WORLDS)) for worlds in WORLD_SETS}
    # layouts are drawn afresh per world: one set alone holds as many distinct layouts as worlds it drew from
    assert len(by_set["train"]) == len(SEEDS) * max(NUM_WORLDS)
    assert not by_set["test"] & by_set["train"]
    assert not by_set["test"] & by_set["validation"]
    assert not by_set["validation"] & by_set["train"]


def test_a_world_is_the_same_whatever_the_number_of_worlds_beside_it():
    # world i of a set is the i-th child of the set's root, so an evaluation on 8 worlds repeats one on 3
    for worlds in WORLD_SETS:
        three = [s.spawn_key for s in world_seeds(5, worlds, 3)]
        eight = [s.spawn_key for s in world_seeds(5, worlds, 8)]
        assert eight[:3] == three


def test_training_worlds_are_the_worlds_a_plain_seed_always_gave():
    plain = np.random.SeedSequence(7).spawn(4)
    assert [s.generate_state(4).tolist() for s in world_seeds(7, "train", 4)] == [
        s.generate_state(4).tolist() for s in plain
    ]


def test_make_env_steps_the_set_it_is_asked_for_and_refuses_another_name():
    first = {}
    for worlds in WORLD_SETS:
        env = evaaa.make_env("1-1", num_envs=2, seed=3, modalities=["interoception"], info=["position"], worlds=worlds)
        assert env.worlds == worlds
        first[worlds] = env.reset()["info", "position"].clone()
        env.set_seed(3)  # torchrl's set_seed keeps the env's set of worlds
        assert env.sim.worlds == worlds
        env.close()
    assert not np.allclose(first["train"], first["test"])
    assert not np.allclose(first["validation"], first["test"])
    with pytest.raises(ValueError, match="worlds must be one of train, validation, test; got 'tests'"):
        evaaa.make_env("1-1", worlds="tests")
