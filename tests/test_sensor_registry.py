"""A new sensor is one module: defining its class registers it, the env, gymnasium and training configs take it by
name, and a key already taken is refused."""

from __future__ import annotations

import importlib
import sys

import gymnasium
import numpy as np
import pytest

import evaaa
from evaaa.sensors import MODALITIES, SENSORS, base

COMPASS = '''
import numpy as np
from evaaa.sensors import Sensor


class Compass(Sensor):
    """The sine and cosine of the body's heading."""
    key = "compass"
    order = 10
    bounds = (-1.0, 1.0)

    @property
    def shape(self):
        return (2,)

    def read(self, worlds):
        heading = self.sim.heading_rad[worlds]
        return np.stack([np.sin(heading), np.cos(heading)], axis=-1).astype(np.float32)
'''


@pytest.fixture
def compass(tmp_path, monkeypatch):
    (tmp_path / "my_compass.py").write_text(COMPASS)
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("my_compass")
    yield module.Compass
    SENSORS.pop("compass", None)  # leave the registry as the other tests expect it
    sys.modules.pop("my_compass", None)


def test_the_packaged_sensors_are_found_in_their_canonical_order():
    assert MODALITIES == ("pixels", "interoception", "olfaction", "thermoception", "collision")
    assert all(SENSORS[k].key == k for k in MODALITIES)


def test_a_sensor_of_ones_own_is_one_class(compass):
    assert SENSORS["compass"] is compass and "compass" not in MODALITIES  # asked for by name, not on by default
    env = evaaa.make_env("1-1", num_envs=2, seed=0, modalities=["compass", "interoception"], threads=1, info=["yaw"])
    assert list(env.sim.modalities) == ["interoception", "compass"]  # canonical order: by `order`
    assert env.observation_spec["compass"].shape == (2, 2)
    td = env.rollout(5, break_when_any_done=False)
    yaw = np.deg2rad(td["next", "info", "yaw"].numpy()[..., 0])  # compass degrees, the same heading
    reading = td["next", "compass"].numpy()
    np.testing.assert_allclose(reading[..., 0], np.sin(yaw), atol=1e-5)
    np.testing.assert_allclose(reading[..., 1], np.cos(yaw), atol=1e-5)
    env.close()

    gym_env = gymnasium.make("evaaa/1-1-v0", modalities=["compass"])
    space = gym_env.observation_space["compass"]
    assert space.shape == (2,) and (space.low == -1).all() and (space.high == 1).all()
    obs, _ = gym_env.reset(seed=0)
    assert obs["compass"].shape == (2,)
    gym_env.close()


def test_training_configs_may_enable_a_sensor_of_ones_own(compass):
    from omegaconf import OmegaConf

    from evaaa_baselines.config import observation_keys

    cfg = OmegaConf.create(
        {"modality": {"name": "with_compass", "enabled": {"interoception": True, "compass": True, "pixels": False}}}
    )
    assert observation_keys(cfg) == ("interoception", "compass")
    cfg.modality.enabled["sonar"] = True
    with pytest.raises(ValueError, match=r"unknown keys \['sonar'\]; known: pixels, .*compass"):
        observation_keys(cfg)


def test_a_key_already_taken_is_refused(compass):
    with pytest.raises(ValueError, match="sensor key 'pixels' is already taken by evaaa.sensors.vision.Vision"):
        type("MyEye", (base.Sensor,), {"key": "pixels", "__module__": "mine"})
    assert SENSORS["pixels"].__name__ == "Vision"
    with pytest.raises(ValueError, match=r"unknown modality 'sonar'; allowed: pixels, .*collision, compass"):
        evaaa.make_env("1-1", modalities=["sonar"])


@pytest.mark.parametrize("algo", ["ppo", "dqn"])
def test_a_sensor_of_ones_own_trains_with_ppo_and_dqn_without_a_config_edit(compass, algo, tmp_path):
    """The encoders give a vector key their config does not list ``algo.encoder.mlp_default`` units: enabling the
    sense on the command line is all it takes."""
    from hydra import compose, initialize_config_dir

    from evaaa_baselines import checkpoint
    from evaaa_baselines.config import register_levels
    from evaaa_baselines.paths import CONF_DIR
    from evaaa_baselines.training import train

    register_levels()  # the level=<name> options
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose(
            "config",
            overrides=[
                f"algo={algo}",
                "preset=debug",
                "logger=csv",
                "progress=false",
                "total_steps=256",
                "device=cpu",
                "modality.enabled.pixels=false",
                "+modality.enabled.compass=true",
            ],
        )
    assert "compass" not in cfg.algo.encoder.mlp
    train(cfg, tmp_path / "run")
    state = checkpoint.load_checkpoint(tmp_path / "run" / checkpoint.CHECKPOINT)
    assert list(state["obs_keys"]) == ["interoception", "olfaction", "thermoception", "collision", "compass"]
    assert state["counters"]["steps"] >= 256
    widths = {k: v.shape for k, v in state["model"].items() if "branches.compass" in k and k.endswith("weight")}
    assert widths and all(shape[0] == cfg.algo.encoder.mlp_default for shape in widths.values()), widths
