"""A reward function is one registered function that declares what it reads (sensor keys, events of the decision):
the simulator hands it exactly that, with no branch on the reward's name, and the level schema takes its name."""

from __future__ import annotations

import numpy as np
import pytest

import evaaa
from evaaa.level import LevelError
from evaaa.physiology import REWARD_FUNCTIONS, REWARDS, register_reward, reward_reads
from evaaa.sensors import SENSORS
from evaaa.sim import NONE, Simulator


@pytest.fixture
def registered():
    names = []

    def add(name, reads, fn):
        register_reward(name, reads=reads)(fn)
        names.append(name)

    yield add
    for name in names:  # leave the registry as the other tests expect it
        REWARD_FUNCTIONS.pop(name, None)


def test_the_packaged_rewards_declare_what_they_read():
    assert REWARDS == ("squared", "drive_reduction", "neg_distance", "sparse", "shaped")
    assert reward_reads("shaped") == ("olfaction", "thermoception", "consumed", "collided")
    assert all(reward_reads(name) == () for name in REWARDS if name != "shaped")
    with pytest.raises(ValueError, match="reward.name must be one of squared, .*shaped, got 'bogus'"):
        reward_reads("bogus")


def test_a_reward_of_ones_own_gets_what_it_declares(registered):
    seen = {}

    def smell_and_bumps(ev_before, ev_after, params, *, olfaction, collided):
        seen.update(olfaction=olfaction, collided=collided)
        return np.asarray(olfaction, dtype=np.float64).sum(axis=-1) - 3.0 * collided

    registered("smell_and_bumps", ("olfaction", "collided"), smell_and_bumps)
    level = evaaa.load_level("two-resource-food", {"reward.name": "smell_and_bumps"})
    sim = Simulator(level, 2, ["interoception"], seed=0, threads=1)  # olfaction is read though not observed
    sim.reset()
    _, r, *_ = sim.step(np.array([NONE, NONE]))
    assert set(seen) == {"olfaction", "collided"} and seen["olfaction"].shape == (2, 10)
    odour = SENSORS["olfaction"](sim).read(np.arange(2))
    assert odour.sum() > 0
    np.testing.assert_allclose(r, odour.sum(axis=-1) - 3.0 * seen["collided"], rtol=1e-6)
    sim.close()


def test_a_reward_that_reads_what_nothing_provides_is_refused_when_the_world_is_built(registered):
    registered("sonar_reward", ("sonar",), lambda ev_before, ev_after, params, *, sonar: ev_after[:, 0])
    level = evaaa.load_level("1-1", {"reward.name": "sonar_reward"})
    with pytest.raises(
        ValueError, match=r"reads sonar, which is neither a sensor key \(.*pixels\) nor an event \(consumed, collided\)"
    ):
        Simulator(level, 1, ["interoception"], seed=0, threads=1)


def test_a_reward_name_already_taken_is_refused_and_unknown_names_are_listed(registered):
    with pytest.raises(ValueError, match="reward name 'squared' is already taken by evaaa.physiology._squared"):
        register_reward("squared")(lambda ev_before, ev_after, params: ev_after[:, 0])
    with pytest.raises(ValueError, match="must be an identifier"):
        register_reward("no such")
    registered("mine", (), lambda ev_before, ev_after, params: -ev_after[:, 0])
    with pytest.raises(LevelError, match=r"reward\.name: must be one of 'squared', .*'shaped', 'mine' \(got 'dense'\)"):
        evaaa.load_level("1-1", {"reward.name": "dense"})
