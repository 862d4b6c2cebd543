"""Where evaaa follows the original EVAAA and where a level option restores it: level contents, vertical
placement, reward semantics, success rules, predator harm, olfaction, night fog, end-type names and the per-step
behaviour log."""

from __future__ import annotations

import numpy as np
import pytest

import evaaa
from evaaa.sim import Simulator
from evaaa.spec import LevelError
from evaaa.worldgen import ObstaclePool, place_obstacles

FOOD_RED = (0.85, 0.08, 0.08)


def _food_pixels(frame: np.ndarray) -> int:
    red = (frame[..., 0] > 150) & (frame[..., 1] < 60) & (frame[..., 2] < 60)
    return int(red.sum())


# ------------------------------------------------------------------------------------------------ level contents
@pytest.mark.parametrize("name", [n for n in evaaa.LEVELS + evaaa.TESTBEDS if evaaa.load_level(n).obstacles])
def test_every_level_holds_every_obstacle_its_file_lists_over_20_seeds(name):
    level = evaaa.load_level(name)
    pool = ObstaclePool.from_level(level)
    listed = {group: spec.count for group, spec in level.obstacles.items()}
    for seed in range(20):
        _, present = place_obstacles(pool, np.random.default_rng(seed))
        held = {group: int(present[pool.group == g].sum()) for g, group in enumerate(pool.names)}
        assert held == listed, f"seed {seed}"


def test_a_level_too_crowded_to_build_fails_naming_the_group():
    level = evaaa.load_level("2-1", {"obstacles.rocks.count": 400, "obstacles.rocks.padding": 6.0})
    pool = ObstaclePool.from_level(level)
    with pytest.raises(LevelError, match=r"obstacles\.rocks: obstacle \d+ of 400"):
        place_obstacles(pool, np.random.default_rng(0))


def test_placement_keeps_the_padding_around_each_new_centre_clear_of_earlier_obstacles():
    pool = ObstaclePool.from_level(evaaa.load_level("2-2"))
    xy, present = place_obstacles(pool, np.random.default_rng(3))
    order = np.flatnonzero(present)
    for i, o in enumerate(order):
        if pool.static[o]:
            continue
        earlier = order[:i]
        gap = np.abs(xy[earlier] - xy[o]) - pool.half[earlier]
        assert (gap.max(axis=1) >= pool.padding[o]).all()


# ------------------------------------------------------------------------------------------------ vertical placement
def test_collision_avoidance_first_frame_shows_the_food_over_the_low_blocks():
    sim = Simulator(evaaa.load_level("collision-avoidance"), 1, ["pixels"], seed=0, threads=1)
    frame = sim.reset()["pixels"][0]
    assert _food_pixels(frame) > 10
    tall = {f"obstacles.b{i:02d}.lift": 0.0 for i in range(1, 12)}  # the blocks resting on the floor, 2.3 m tall
    sim_tall = Simulator(evaaa.load_level("collision-avoidance", tall), 1, ["pixels"], seed=0, threads=1)
    assert _food_pixels(sim_tall.reset()["pixels"][0]) == 0
    sim.close()
    sim_tall.close()


def _tops(sim: Simulator) -> np.ndarray:
    """Height above the floor of the top of each obstacle slot."""
    return sim.obstacles.centre_z() + sim.obstacles.extents[:, 2] / 2


@pytest.mark.parametrize("name, top", [("collision-avoidance", 0.55), ("goal-manipulation-food-to-water", 0.5),
                                       ("two-resource-food", 4.0), ("risk-taking", 4.0), ("y-maze", 4.0),
                                       ("multi-goal-planning", 4.0)])
def test_testbed_blocks_stand_as_high_as_the_originals(name, top):
    sim = Simulator(evaaa.load_level(name), 1, ["collision"], seed=0, threads=1)
    sim.reset()
    blocks = sim.obstacles.kind == "block"
    assert np.allclose(_tops(sim)[blocks], top)
    # the compiled scene agrees: each block's geom reaches that height
    model = sim.model
    for o in np.flatnonzero(blocks):
        body = model.body(f"obs{o}")
        geom = model.geom(body.geomadr[0])
        z = body.pos[2] if model.body_mocapid[body.id] < 0 else sim.datas[0].mocap_pos[model.body_mocapid[body.id], 2]
        assert z + geom.size[2] == pytest.approx(top)
    sim.close()


def test_testbed_walls_stand_4_5_m_and_a_low_block_still_stops_the_rays_and_the_body():
    level = evaaa.load_level("goal-manipulation-food-to-water")
    assert level.arena.wall_height == 4.5
    sim = Simulator(level, 1, ["collision"], seed=0, threads=1)
    sim.reset()
    # face the 0.5 m strip (x -15 ... 5 at y = -7) from 1 m north of it: the rays at the body centre's height see it
    sim.set_agent_pose(0, (-5.0, -5.6), 180.0)
    assert sim.last_obs["collision"][0, 0] == 1.0
    for _ in range(5):
        sim.step(np.array([1]))
    # the strip's north face is at y = -6.5 and the body's half-width 0.5: it stops there (soft contacts give ~0.1)
    assert sim.pos[0, 1] > -6.2
    sim.close()
