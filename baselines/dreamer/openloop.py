"""Open-loop prediction pictures, written during training every ``algo.openloop.every`` gradient steps: the world
model filters a few replayed steps, then imagines the rest from the real actions alone; real frames, the model's and
their difference side by side.  Drawn on their own RNG stream, so training does not depend on them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase

from .model import DreamerModel, next_keys, one_hot_action, world_model
from .replay import SequenceReplay


@torch.no_grad()
def openloop_frames(model: DreamerModel, sequences: TensorDictBase, context: int) -> tuple[torch.Tensor, ...]:
    """Real and predicted frames of ``sequences`` (``[n, T]`` from the replay buffer): the world model filters the
    first ``context`` steps (posterior), then imagines the rest from the real actions alone (prior, open loop).
    Returns uint8 ``[n, T, H, W, 3]`` truth and model."""
    n, length = sequences.shape
    seq = sequences.select("action", "is_init", *next_keys(*model.obs_keys)).clone()
    device = next(model.parameters()).device
    seq["state"] = torch.zeros(n, length, model.state_dim, device=device)
    seq["belief"] = torch.zeros(n, length, model.belief_dim, device=device)
    filtered = world_model(model)[:3](seq[:, :context])  # one-hot, encoder, RSSM rollout
    state, belief = filtered["next", "state"][:, -1], filtered["next", "belief"][:, -1]
    states, beliefs = [filtered["next", "state"]], [filtered["next", "belief"]]
    actions = one_hot_action(seq["action"][:, context:])
    for t in range(length - context):
        _, state, belief = model.prior(state, belief, actions[:, t])
        states.append(state.unsqueeze(1))
        beliefs.append(belief.unsqueeze(1))
    pixel_index = model.decoder.keys.index("pixels")
    predicted = model.decoder(torch.cat(states, 1), torch.cat(beliefs, 1))[pixel_index]
    truth = seq["next", "pixels"]
    return truth.cpu(), (predicted.float().clamp(0, 1) * 255).round().to(torch.uint8).cpu()


def openloop_grid(truth: torch.Tensor, predicted: torch.Tensor, context: int) -> np.ndarray:
    """Per sequence three rows — real frames, the model's, their absolute difference — one column per step; a
    white bar under the filtered (context) steps tells them from the imagined ones."""
    n, length, height, width, _ = truth.shape
    gap = 2
    error = (truth.float() - predicted.float()).abs().clamp(0, 255).to(torch.uint8)
    cell_h, cell_w = height + gap, width + gap
    grid = np.full((n * (3 * cell_h + 2 * gap), length * cell_w, 3), 32, dtype=np.uint8)
    for i in range(n):
        top = i * (3 * cell_h + 2 * gap)
        for r, frames in enumerate((truth, predicted, error)):
            for t in range(length):
                y, x = top + r * cell_h, t * cell_w
                grid[y : y + height, x : x + width] = frames[i, t].numpy()
        bar = top + 3 * cell_h
        grid[bar : bar + gap, : context * cell_w - gap] = 255
    return grid


def save_openloop(model: DreamerModel, replay: SequenceReplay, cfg: DictConfig, path: Path) -> Path | None:
    """An open-loop picture of ``cfg.openloop.sequences`` random replayed sequences (``context`` filtered steps,
    then ``horizon`` imagined ones) as a PNG; drawn on its own RNG stream, so training does not depend on it."""
    length = cfg.openloop.context + cfg.openloop.horizon
    if "pixels" not in model.decoder.keys or replay.rows < length:
        return None
    import matplotlib.image

    device = next(model.parameters()).device
    with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        torch.manual_seed(len(replay.buffer))
        sequences = replay.sample(cfg.openloop.sequences, length)
        truth, predicted = openloop_frames(model, sequences, cfg.openloop.context)
    path.parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(path, openloop_grid(truth, predicted, cfg.openloop.context))
    return path
