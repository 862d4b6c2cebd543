"""The MuJoCo Warp backend (``backend="warp"``, :mod:`evaaa.mjwarp`) on Warp's CPU device.

Tests that run kernels are marked slow: the first run compiles Warp's kernels (a few minutes on a CPU) into the
cache of :func:`evaaa.mjwarp.kernel_cache_dir`; with the cache kept they take well under a minute together.
Without the optional packages (``pip install -e '.[warp]'``) every test that needs them is skipped, saying so.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

import evaaa
from evaaa import mjwarp
from evaaa.backends import make_simulator
from evaaa.level_files import load_level
from evaaa.sim import SUBSTEPS, Simulator

needs_warp = pytest.mark.skipif(
    not mjwarp.available(), reason="mujoco-warp and warp-lang are not installed (the optional extra 'warp')"
)

#: the frames of day levels: mean absolute difference from the CPU's OpenGL frames, of 255 per channel
DAY_FRAME_TOLERANCE = 2.0
#: at night (fog, far plane, the dimmed lights, the sky switched off) and at dusk and dawn
NIGHT_FRAME_TOLERANCE = 8.0


# ------------------------------------------------------------------------------------------------ no kernels
def test_an_unknown_backend_is_refused_naming_the_field_and_the_choices():
    with pytest.raises(ValueError, match=r"backend must be one of 'cpu', 'warp'; got 'gpu'"):
        evaaa.make_env("1-1", backend="gpu")
    with pytest.raises(ValueError, match="backend must be one of"):
        evaaa.gym.EvaaaGymEnv("1-1", backend="GPU")
    assert evaaa.BACKENDS == ("cpu", "warp")


def test_a_missing_mujoco_warp_names_the_extra_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco_warp", None)  # import mujoco_warp now fails
    with pytest.raises(ImportError, match=r"mujoco-warp and warp-lang.*\.\[warp\]"):
        evaaa.make_env("1-1", backend="warp")


def test_the_kernel_cache_is_where_the_environment_says(monkeypatch, tmp_path):
    monkeypatch.delenv("WARP_CACHE_PATH", raising=False)
    monkeypatch.delenv("EVAAA_WARP_CACHE", raising=False)
    assert str(mjwarp.kernel_cache_dir()).endswith(".cache/evaaa-warp")
    monkeypatch.setenv("EVAAA_WARP_CACHE", str(tmp_path))
    assert mjwarp.kernel_cache_dir() == tmp_path


@needs_warp
@pytest.mark.parametrize("name", evaaa.LEVELS + evaaa.TESTBEDS)
def test_every_level_and_testbed_is_accepted_by_put_model(name):
    import mujoco
    import mujoco_warp as mjw

    from evaaa.scene import build_mjcf

    sim = Simulator(load_level(name), 1, modalities=["interoception"], seed=0, threads=1)
    mjm = mujoco.MjModel.from_xml_string(build_mjcf(sim.level, sim.pool, sim.obstacles, head_light=True))
    assert mjm.nq == sim.model.nq and mjm.nmocap == sim.model.nmocap and mjm.nlight == sim.model.nlight + 1
    mjwarp.load_warp()
    model = mjw.put_model(mjm, batch_sizes={"light_diffuse": 2, "light_ambient": 2})
    assert model.nmocap == sim.model.nmocap
    nconmax, njmax = mjwarp.buffer_sizes(mjm)
    assert 8 <= nconmax <= 48 and njmax >= 4 * nconmax


# ------------------------------------------------------------------------------------------------ kernels
@pytest.fixture(scope="module")
def pair():
    """Warp and CPU simulators of one level with the same worlds (4 worlds; made once per level)."""
    made = {}

    def get(name: str):
        if name not in made:
            level = load_level(name)
            made[name] = (
                make_simulator(level, 4, seed=3, backend="warp", device="cpu"),
                make_simulator(level, 4, seed=3, threads=1),
            )
            for sim in made[name]:
                sim.reset()
        return made[name]

    yield get
    for sims in made.values():
        for sim in sims:
            sim.close()


def lock_step(warp_sim, cpu_sim) -> None:
    """Give the Warp simulator the CPU one's poses and velocities (float32 rounding apart)."""
    for w in range(cpu_sim.n):
        warp_sim.datas[w].qpos[:] = cpu_sim.datas[w].qpos
        warp_sim.datas[w].qvel[:] = cpu_sim.datas[w].qvel
    warp_sim.state.pos[:] = cpu_sim.state.pos
    warp_sim.state.heading_rad[:] = cpu_sim.state.heading_rad


@needs_warp
@pytest.mark.slow
def test_physics_matches_mj_step_within_1e_4_over_a_decision_without_contacts(pair):
    warp_sim, cpu_sim = pair("1-1")
    for actions in ([1, 1, 1, 1], [2, 3, 1, 0], [1, 2, 1, 3]):
        lock_step(warp_sim, cpu_sim)
        start = np.stack([d.qpos.copy() for d in cpu_sim.datas])
        _, _, _, _, warp_info = warp_sim.step(np.array(actions))
        _, _, _, _, cpu_info = cpu_sim.step(np.array(actions))
        assert not cpu_info["collision"].any() and not warp_info["collision"].any()
        warp_q = np.stack([d.qpos for d in warp_sim.datas])
        cpu_q = np.stack([d.qpos for d in cpu_sim.datas])
        moved = np.abs(cpu_q - start).max()
        assert moved > 0.05 or actions != [1, 1, 1, 1]  # the bodies went somewhere
        assert np.abs(warp_q - cpu_q).max() < 1e-4
        assert np.abs(warp_sim.state.pos - cpu_sim.state.pos).max() < 1e-4


@needs_warp
@pytest.mark.slow
def test_collision_damage_comes_from_the_device_contact_forces(pair):
    warp_sim, cpu_sim = pair("1-1")
    # walk both into the east wall, facing it
    hx = cpu_sim.level.arena.size[0] / 2
    for sim in (warp_sim, cpu_sim):
        for w in range(sim.n):
            sim.set_agent_pose(w, (hx - 1.0, 0.0), 90.0)
    hits = {"warp": 0, "cpu": 0}
    damage = {"warp": 0.0, "cpu": 0.0}
    for _ in range(4):
        for key, sim in (("warp", warp_sim), ("cpu", cpu_sim)):
            _, _, _, _, info = sim.step(np.ones(sim.n, dtype=np.int64))
            hits[key] += int(info["collision"].sum())
            damage[key] += float(info["damage_taken"].sum())
    assert hits["cpu"] > 0 and hits["warp"] > 0
    assert damage["warp"] == pytest.approx(damage["cpu"], rel=0.25)
    assert np.abs(warp_sim.state.pos - cpu_sim.state.pos).max() < 0.05  # both stopped at the wall


def frame_difference(warp_sim, cpu_sim) -> np.ndarray:
    """Mean absolute difference (of 255, per channel) of each world's eye frame on the two backends."""
    worlds = np.arange(cpu_sim.n)
    warp_frames = warp_sim.render_eye(worlds)
    assert isinstance(warp_frames, torch.Tensor) and warp_frames.dtype == torch.uint8
    assert tuple(warp_frames.shape) == (cpu_sim.n, 64, 64, 3)
    cpu_frames = cpu_sim.render_eye(worlds)
    return np.abs(warp_frames.cpu().numpy().astype(float) - cpu_frames.astype(float)).mean(axis=(1, 2, 3))


@needs_warp
@pytest.mark.slow
def test_day_frames_match_the_opengl_frames(pair):
    warp_sim, cpu_sim = pair("1-1")
    lock_step(warp_sim, cpu_sim)
    diff = frame_difference(warp_sim, cpu_sim)
    assert diff.max() < DAY_FRAME_TOLERANCE, diff


@needs_warp
@pytest.mark.slow
def test_night_frames_match_within_the_stated_tolerance(pair):
    warp_sim, cpu_sim = pair("4-2")
    lock_step(warp_sim, cpu_sim)
    # noon, sunset, deep night, dawn
    for angles in ([90.0, 185.0, 270.0, 350.0], [200.0, 240.0, 330.0, 345.0]):
        for sim in (warp_sim, cpu_sim):
            sim.state.sun_angle[:] = angles
        diff = frame_difference(warp_sim, cpu_sim)
        assert diff.max() < NIGHT_FRAME_TOLERANCE, (angles, diff)
    # the same worlds are darker at midnight than at noon
    brightness = {}
    for angle in (90.0, 270.0):
        warp_sim.state.sun_angle[:] = angle
        brightness[angle] = warp_sim.render_eye(np.arange(4)).float().mean(dim=(1, 2, 3))
    assert (brightness[270.0] < 0.5 * brightness[90.0]).all(), brightness


@needs_warp
@pytest.mark.slow
@pytest.mark.parametrize("name", ["1-1", "4-2"])
def test_check_env_specs_and_the_contract_equal_the_cpu_backends(name):
    env = evaaa.make_env(name, num_envs=2, seed=0, backend="warp", info=True)
    cpu = evaaa.make_env(name, num_envs=2, seed=0, info=True)
    try:
        assert env.backend == "warp" and "backend='warp'" in repr(env)
        check_env_specs(env, seed=0)
        assert env.observation_spec == cpu.observation_spec
        assert env.action_spec == cpu.action_spec and env.reward_spec == cpu.reward_spec
        assert env.done_spec == cpu.done_spec
        td = env.rollout(3)
        reference = cpu.rollout(3)
        for key in reference.keys(include_nested=True, leaves_only=True):
            assert td[key].shape == reference[key].shape and td[key].dtype == reference[key].dtype, key
        # a partial reset keeps the other world's frame
        td = env.reset()
        frames = td["pixels"].clone()
        td["_reset"] = torch.tensor([[True], [False]])
        after = env.reset(td)
        assert torch.equal(after["pixels"][1], frames[1])
    finally:
        env.close()
        cpu.close()


@needs_warp
@pytest.mark.slow
def test_the_gymnasium_adapter_gives_numpy_observations_on_warp():
    env = evaaa.gym.EvaaaGymEnv("1-1", backend="warp", render_mode="rgb_array")
    try:
        obs, _ = env.reset(seed=0)
        assert isinstance(obs["pixels"], np.ndarray) and obs["pixels"].shape == (64, 64, 3)
        assert env.observation_space.contains(obs)
        obs, *_ = env.step(1)
        assert env.observation_space.contains(obs)
        assert isinstance(env.render(), np.ndarray)
    finally:
        env.close()


@needs_warp
@pytest.mark.slow
def test_a_short_ppo_run_trains_on_the_warp_backend(tmp_path):
    from hydra import compose, initialize_config_dir

    from evaaa_baselines import checkpoint
    from evaaa_baselines.config import register_levels
    from evaaa_baselines.paths import CONF_DIR
    from evaaa_baselines.training import train

    register_levels()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose(
            "config",
            overrides=[
                "algo=ppo",
                "preset=debug",
                "logger=csv",
                "progress=false",
                "total_steps=64",
                "env.backend=warp",
            ],
        )
    train(cfg, tmp_path / "run")
    state = checkpoint.load_checkpoint(tmp_path / "run" / checkpoint.CHECKPOINT)
    assert state["counters"]["steps"] == 64 and state["config"]["env"]["backend"] == "warp"
    assert (tmp_path / "run" / "model-0-1-1.pt").exists()


@needs_warp
@pytest.mark.slow
def test_bench_env_measures_the_warp_backend_beside_the_cpu_one(tmp_path):
    import json

    from helpers import load_script

    out = tmp_path / "bench" / "warp.json"
    args = ["backend=warp", "levels=[1-1]", "counts=[2]", "warp_steps=3", "cpu_max_worlds=2", f"json={out}"]
    assert load_script("bench_env").main(args) == 0
    figures = json.loads(out.read_text())
    assert figures["backend"] == "warp" and figures["warp_device"] == "cpu" and figures["counts"] == [2]
    rows = {row["backend"]: row for row in figures["rows"]}
    assert set(rows) == {"warp", "cpu"} and all(row["env_steps_per_s"] > 0 for row in rows.values())
    split = rows["warp"]["seconds_per_decision"]
    assert set(split) == {"sync", "physics", "camera", "total"} and split["physics"] > 0
    assert split["sync"] + split["physics"] + split["camera"] <= split["total"] * 1.01


def test_substeps_are_the_cpu_backends():
    assert SUBSTEPS == 5  # the device steps the same five substeps of 0.02 s per decision


def test_training_refuses_an_unknown_backend_naming_the_key():
    from hydra import compose, initialize_config_dir

    from evaaa_baselines.config import ConfigError, check_values, register_levels
    from evaaa_baselines.paths import CONF_DIR

    register_levels()
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["env.backend=gpu", "device=cpu"])
        assert compose("config").env.backend == "cpu"  # the default
    with pytest.raises(ConfigError, match=r"env\.backend=gpu: expected one of cpu, warp"):
        check_values(cfg)
