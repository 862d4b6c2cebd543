"""The gymnasium adapter: API conformance, registration, spaces, seeding, action validation, truncation."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from helpers import decode_mp4

import evaaa
from evaaa.gym import EvaaaGymEnv, register_envs

ACTIONS = np.random.default_rng(0).integers(0, 5, size=30)


def rollout(seed: int) -> tuple[list[dict[str, np.ndarray]], list[float]]:
    env = gymnasium.make("evaaa/1-1-v0")
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    for action in ACTIONS:
        obs, reward, _, _, _ = env.step(int(action))
        observations.append(obs)
        rewards.append(reward)
    env.close()
    return observations, rewards


# the float observations are unbounded by design, so check_env's "infinite Box" advice is expected; any other
# warning from the checker is an API problem and fails the test
@pytest.mark.filterwarnings("ignore:.*Box observation space (minimum|maximum) value is")
@pytest.mark.filterwarnings("error")
def test_check_env_passes():
    env = gymnasium.make("evaaa/1-1-v0")
    check_env(env.unwrapped)
    env.close()


def test_every_level_is_registered():
    for name in evaaa.LEVELS:
        spec = gymnasium.spec(f"evaaa/{name}-v0")
        assert spec.entry_point == "evaaa.gym:EvaaaGymEnv"
        assert spec.kwargs == {"level": name}


@pytest.mark.filterwarnings("error")
def test_register_envs_twice_is_harmless():
    before = dict(gymnasium.registry)
    register_envs()
    assert dict(gymnasium.registry) == before


def test_observation_keys_follow_modalities():
    env = gymnasium.make("evaaa/1-1-v0", modalities=["interoception", "olfaction"])
    assert set(env.observation_space.spaces) == {"interoception", "olfaction"}
    obs, info = env.reset(seed=0)
    assert set(obs) == {"interoception", "olfaction"}
    assert obs in env.observation_space
    obs, *_ = env.step(1)
    assert set(obs) == {"interoception", "olfaction"}
    assert obs in env.observation_space
    env.close()


def test_reset_info_is_plain():
    env = gymnasium.make("evaaa/1-1-v0", modalities="interoception")
    _, info = env.reset(seed=0)
    assert info["end_type_name"] == "None"
    assert type(info["step_count"]) is int and type(info["collision"]) is bool
    assert type(info["satiation"]) is float
    assert info["position"].shape == (3,)
    env.close()


def test_same_seed_same_episode_different_seed_different():
    obs_a, rew_a = rollout(7)
    obs_b, rew_b = rollout(7)
    obs_c, rew_c = rollout(8)
    assert rew_a == rew_b
    for a, b in zip(obs_a, obs_b):
        assert a.keys() == b.keys() and "pixels" in a
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    assert rew_a != rew_c
    assert not all(np.array_equal(a["pixels"], c["pixels"]) for a, c in zip(obs_a, obs_c))


@pytest.mark.parametrize("action", [5, -1, True, False, np.bool_(True)])  # booleans are not actions either
def test_invalid_action_raises(action):
    env = gymnasium.make("evaaa/1-1-v0", modalities="interoception")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be an integer in 0\.\.4"):
        env.step(action)
    env.close()


def test_max_steps_truncates():
    env = gymnasium.make("evaaa/1-1-v0", modalities="interoception", **{"episode.max_steps": 5})
    env.reset(seed=0)
    for _ in range(4):
        _, _, terminated, truncated, _ = env.step(0)
        assert not terminated and not truncated
    _, _, terminated, truncated, info = env.step(0)
    assert truncated is True and terminated is False
    assert info["end_type_name"] == "MaxStepReached"
    env.close()


def test_render_is_the_eye_view_without_pixels():
    seen = gymnasium.make("evaaa/1-1-v0", modalities="pixels")
    blind = gymnasium.make("evaaa/1-1-v0", modalities="interoception", render_mode="rgb_array")
    obs, _ = seen.reset(seed=3)
    blind.reset(seed=3)
    np.testing.assert_array_equal(blind.render(), obs["pixels"])
    seen.close()
    blind.close()


def test_unknown_render_mode_raises():
    with pytest.raises(ValueError, match="rgb_array"):
        EvaaaGymEnv("1-1", render_mode="human")


def test_registration_carries_the_level_step_cap():
    for name in evaaa.LEVELS + evaaa.TESTBEDS:
        assert gymnasium.spec(f"evaaa/{name}-v0").max_episode_steps == evaaa.load_level(name).episode.max_steps
    env = gymnasium.make("evaaa/two-resource-food-v0", modalities="interoception")
    assert env.spec.max_episode_steps == evaaa.load_level("two-resource-food").episode.max_steps
    env.close()


def test_a_longer_cap_than_registered_warns_about_gymnasium_time_limit():
    with pytest.warns(UserWarning, match=r"also pass max_episode_steps=9000"):
        env = EvaaaGymEnv("1-1", modalities="interoception", **{"episode.max_steps": 9000})
    assert env.unwrapped.level.episode.max_steps == 9000  # the override itself is kept
    env.close()


def test_the_collision_sensor_is_declared_zero_or_one():
    env = gymnasium.make("evaaa/1-1-v0", modalities=["collision", "olfaction"])
    space = env.observation_space["collision"]
    assert (space.low == 0).all() and (space.high == 1).all()
    assert np.isinf(env.observation_space["olfaction"].high).all()  # the others stay unbounded
    env.close()


def test_stepping_a_closed_env_is_an_error():
    env = EvaaaGymEnv("1-1", modalities="interoception", render_mode="rgb_array")
    env.reset(seed=0)
    env.close()
    for call in (lambda: env.step(0), lambda: env.reset(seed=0), env.render):
        with pytest.raises(RuntimeError, match=r"EvaaaGymEnv \(1-1\) was closed"):
            call()
    env.close()  # closing twice is harmless (wrappers and garbage collection both close)
    assert env.sim._renderer is None  # nothing was rebuilt


def test_repr_names_the_level_and_modalities():
    env = EvaaaGymEnv("1-2", modalities=["olfaction"])
    assert repr(env) == "EvaaaGymEnv(level='1-2', modalities=['olfaction'], render_mode=None, max_steps=5000)"
    env.close()


def test_rendered_frames_make_a_playable_video(tmp_path):
    from evaaa.video import write_mp4

    env = gymnasium.make("evaaa/1-1-v0", modalities="interoception", render_mode="rgb_array")
    env.reset(seed=0)
    frames = [env.render()]
    for action in ACTIONS[:9]:
        env.step(int(action))
        frames.append(env.render())
    env.close()
    path = write_mp4(tmp_path / "eye.mp4", frames, fps=10)
    decoded = decode_mp4(path)
    assert len(decoded) == 10 and decoded[0].shape == (64, 64, 3)
    # lossy, but each decoded frame is closer to its own source frame than to the others
    for i, frame in enumerate(decoded):
        errors = [np.abs(frame.astype(int) - f.astype(int)).mean() for f in frames]
        assert errors[i] == min(errors) and errors[i] < 20, (i, errors)
