"""What makes training cheaper without changing what it computes: PPO's single-call GAE gives the advantages and
value targets of the two-call one (truncations and terminations inside a rollout included), the minibatches
leave the next step's frames behind, the time split counts each phase and refuses a phase it does not know, and
the allocator setting takes on this machine's C library."""

from __future__ import annotations

import time

import pytest
import torch
from omegaconf import OmegaConf
from tensordict import TensorDict
from torchrl.objectives.value import GAE

from evaaa_baselines import ppo
from evaaa_baselines.machine import keep_freed_memory
from evaaa_baselines.paths import CONF_DIR
from evaaa_baselines.stage import PHASES, TimeSplit, shares

SHAPES = {"pixels": (64, 64, 3), "interoception": (4,)}


def PAPER_PPO():  # noqa: N802 - PPO with the paper's sizes: four stacked frames, as the rollouts below are made
    return OmegaConf.merge(
        OmegaConf.load(CONF_DIR / "algo" / "ppo.yaml"),
        OmegaConf.load(CONF_DIR / "preset" / "algo" / "ppo_paper_sizes.yaml"),
    )


#: where episodes end in the rollouts below, (world, step) -> terminated: world 0 truncated at step 5, world 1
#: terminated at step 9; with TWICE, world 2 truncated at steps 3 and 11 too (more than the single call's budget)
ONCE = {(0, 5): False, (1, 9): True}
TWICE = ONCE | {(2, 3): False, (2, 11): False}


def _rollout(worlds: int, steps: int, ends: dict, seed: int = 0) -> TensorDict:
    """A ``[worlds, steps]`` rollout as the env and CatFrames make it: ``next`` observations equal the following
    step's except where an episode ended (``ends``)."""
    g = torch.Generator().manual_seed(seed)
    pixels = torch.randint(0, 256, (worlds, steps + 1, 64, 64, 12), dtype=torch.uint8, generator=g)
    intero = torch.randn(worlds, steps + 1, 4, generator=g)
    done = torch.zeros(worlds, steps, 1, dtype=torch.bool)
    terminated = torch.zeros_like(done)
    next_pixels, next_intero = pixels[:, 1:].clone(), intero[:, 1:].clone()
    for (w, t), term in ends.items():
        done[w, t] = True
        terminated[w, t] = term
        # the episode's last observation differs from the reset observation the next step starts from
        next_pixels[w, t] = torch.randint(0, 256, (64, 64, 12), dtype=torch.uint8, generator=g)
        next_intero[w, t] = torch.randn(4, generator=g)
    return TensorDict(
        {
            "pixels": pixels[:, :-1],
            "interoception": intero[:, :-1],
            "next": {
                "pixels": next_pixels,
                "interoception": next_intero,
                "reward": torch.randn(worlds, steps, 1, generator=g),
                "done": done,
                "terminated": terminated,
            },
        },
        [worlds, steps],
    )


@pytest.mark.parametrize("ends", [ONCE, TWICE], ids=["single-call", "two-truncations-the-long-way"])
def test_single_call_gae_gives_the_two_call_advantages_across_truncations_and_terminations(ends, monkeypatch):
    cfg = PAPER_PPO()
    torch.manual_seed(0)
    model = ppo.make_model(cfg, SHAPES)
    batch = _rollout(worlds=3, steps=16, ends=ends)
    calls = []
    monkeypatch.setattr(GAE, "forward", _counting(GAE.forward, calls))
    reference = batch.clone()
    # the reference: torchrl's GAE as it comes, the critic called on the steps and again on their next steps
    two_calls = GAE(gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=model.get_value_operator(), average_gae=False)
    with torch.no_grad():
        two_calls(reference)
        calls.clear()
        ppo.make_advantage(cfg, model)(batch)
    for key in ("advantage", "value_target", "state_value"):
        torch.testing.assert_close(batch[key], reference[key], rtol=1e-5, atol=1e-5)
    # one call of the single-call estimator, and a second, the long way, only where a world truncated twice
    assert calls == ([True] if ends is ONCE else [True, False])
    assert "shifted_valid" not in batch.keys()
    assert batch.names == [None, None]


def _counting(forward, calls: list):
    def counted(self, *args, **kwargs):
        if self.value_network is not None and len(calls) < 10:
            calls.append(bool(self.shifted))
        return forward(self, *args, **kwargs)

    return counted


def test_the_single_call_changes_the_values_a_wrong_next_observation_would_give():
    """The check above can fail: with the truncated step's next observation replaced by the reset one (what a naive
    shift does), the advantage of that step changes."""
    cfg = PAPER_PPO()
    torch.manual_seed(0)
    model = ppo.make_model(cfg, SHAPES)
    batch = _rollout(worlds=3, steps=16, ends=ONCE)
    naive = batch.clone()
    naive["next", "pixels"][0, 5] = naive["pixels"][0, 6]
    naive["next", "interoception"][0, 5] = naive["interoception"][0, 6]
    with torch.no_grad():
        ppo.make_advantage(cfg, model)(batch)
        ppo.make_advantage(cfg, model)(naive)
    assert not torch.allclose(batch["advantage"][0, 5], naive["advantage"][0, 5])
    torch.testing.assert_close(batch["advantage"][1], naive["advantage"][1])


def test_the_time_split_counts_each_phase_and_the_rest():
    split = TimeSplit()
    with split("env"):
        time.sleep(0.05)
    with split("forward"):
        sum(i * i for i in range(200_000))  # CPU work
    assert split.wall["env"] >= 0.05
    assert split.cpu["env"] < 0.04  # sleeping costs no CPU
    assert split.cpu["forward"] > 0.0
    assert split.wall["backward"] == 0.0
    scalars = split.scalars()
    assert set(scalars) == {f"time/{kind}/{p}" for kind in ("cpu", "wall") for p in (*PHASES, "total")}
    assert scalars["time/wall/total"] >= split.wall["env"] + split.wall["forward"]
    parts = shares({"env": 1.0, "forward": 2.0}, 4.0)
    assert parts == {"env": 0.25, "forward": 0.5, "other": 0.25}


def test_the_time_split_refuses_a_phase_it_does_not_know():
    with pytest.raises(ValueError, match="no phase 'learn'.*env, act"):
        with TimeSplit()("learn"):
            pass


def test_freed_memory_is_kept_for_reuse_on_glibc():
    assert keep_freed_memory() is True
