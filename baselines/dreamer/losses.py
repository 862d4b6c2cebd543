"""The losses of DreamerV3's gradient step beyond torchrl's: :class:`WorldModelLoss` (``DreamerV3ModelLoss`` plus
the extra vector-key reconstruction terms, in symlog or raw space), the critic's loss on the replayed sequences
(:func:`replay_value_loss`), and :func:`diagnostics`, what a logged gradient step reports beside its losses.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.objectives import DreamerV3ModelLoss, DreamerV3ValueLoss

from evaaa import ACTION_NAMES

from ..nets import symlog
from .model import LATENT, DreamerDecoder, DreamerModel, world_model


# ------------------------------------------------------------------------------------------------ losses
def vector_reconstruction(posterior: TensorDictBase, keys: Sequence[str], raw: Sequence[str] = ()) -> torch.Tensor:
    """The vector keys' reconstruction loss as ``DreamerV3ModelLoss`` counts it (squared error in symlog space, or
    in raw units for the keys in ``raw``, summed over each key's entries, averaged over the replayed steps), summed
    over ``keys``.  With pixels it is a small part of the loss (4 EVs against 12,288 pixel values):
    ``algo.world_model.vector_scale`` weighs it more."""
    return _vector_error(
        {k: posterior["next", k] for k in keys}, {k: posterior["next", f"reco_{k}"] for k in keys}, raw
    )


def _vector_error(
    target: Mapping[str, torch.Tensor], predicted: Mapping[str, torch.Tensor], raw: Sequence[str] = ()
) -> torch.Tensor:
    def space(k: str, x: torch.Tensor) -> torch.Tensor:
        return x.float() if k in raw else symlog(x.float())

    return sum(((space(k, target[k]) - space(k, predicted[k])) ** 2).sum(-1).mean() for k in target)


def prior_vector_reconstruction(
    posterior: TensorDictBase,
    decoder: DreamerDecoder,
    keys: Sequence[str],
    raw: Sequence[str] = (),
    unimix: float = 0.01,
) -> torch.Tensor:
    """The vector keys of each next observation decoded from the *prior* (a straight-through draw of its latent,
    with the deterministic state the action led to) instead of the posterior that saw it, scored as
    :func:`vector_reconstruction`: a one-step latent overshooting term (``algo.world_model.prior_vector_scale``)
    that trains the transition, through the decoder, to predict what an action does to the EVs.  Without it only
    the dynamics KL teaches the prior, and a meal, under 1 % of the steps, barely moves it (docs/training.md)."""
    nxt = posterior["next"]
    probs = torch.softmax(nxt["prior_logits"].float(), dim=-1)
    probs = (1 - unimix) * probs + unimix / probs.shape[-1]
    state = torch.distributions.OneHotCategoricalStraightThrough(probs=probs).rsample().flatten(-2)
    predicted = decoder.vectors(state, nxt["belief"], keys)
    return _vector_error({k: nxt[k] for k in keys}, predicted, raw)


class WorldModelLoss(nn.Module):
    """The world model's loss on a replayed batch: torchrl's ``DreamerV3ModelLoss`` (KL balancing with dynamics /
    representation weights, free nats and unimix; pixels as x/255 and the vector keys in symlog space; two-hot
    reward; continue predicted from ``terminated``, not truncation), plus ``algo.world_model.vector_scale - 1``
    times the vector keys' reconstruction.  The keys in ``algo.world_model.raw_keys`` are reconstructed in raw units
    instead of symlog space: symlog squeezes a meal's +3.3 satiation at -8 to a change of 0.34.  Returns the total,
    the loss's terms, the posterior (detached) and the vector keys' reconstruction loss (None without vector
    keys)."""

    def __init__(self, cfg: DictConfig, model: DreamerModel):
        super().__init__()
        keys = model.obs_keys
        self.vector_keys = [k for k in keys if k != "pixels"]
        self.vector_extra = float(cfg.world_model.get("vector_scale", 1.0)) - 1.0
        self.prior_scale = float(cfg.world_model.get("prior_vector_scale", 0.0))
        if self.prior_scale < 0 or (self.prior_scale and not self.vector_keys):
            raise ValueError(
                f"algo.world_model.prior_vector_scale must be >= 0, and 0 without vector observation "
                f"keys (this run has {self.vector_keys}), got {self.prior_scale}"
            )
        self.decoder, self.unimix = model.decoder, float(cfg.model.unimix)
        raw = cfg.world_model.get("raw_keys", ())
        self.raw_keys = (raw,) if isinstance(raw, str) else tuple(raw)  # one key may come as a plain string
        if not set(self.raw_keys) <= set(self.vector_keys):
            raise ValueError(
                f"algo.world_model.raw_keys must name vector observation keys of this run "
                f"({self.vector_keys}), got {list(self.raw_keys)}"
            )
        decoded = model.decoder.keys
        symlogged = [k != "pixels" and k not in self.raw_keys for k in decoded]
        self.loss = DreamerV3ModelLoss(
            world_model(model),
            kl_mode="separate",
            lambda_dynamic=cfg.world_model.kl_dynamic,
            lambda_representation=cfg.world_model.kl_representation,
            free_bits=cfg.world_model.free_nats,
            unimix=cfg.model.unimix,
            lambda_continue=cfg.world_model.continue_scale,
            reco_loss="l2",
            reco_symlog=symlogged,
            reward_two_hot=True,
            num_reward_bins=cfg.model.bins,
            # the vector keys' extra reconstruction term needs the graph; everything else reads the output detached
            detach_output=not (self.vector_extra or self.prior_scale),
        )
        self.loss.set_keys(pixels=list(decoded), reco_pixels=[f"reco_{k}" for k in decoded])

    def forward(
        self, batch: TensorDictBase
    ) -> tuple[torch.Tensor, TensorDictBase, TensorDictBase, torch.Tensor | None]:
        losses, posterior = self.loss(batch)
        total = sum(v for k, v in losses.items() if k.startswith("loss_")).squeeze()
        vector_reco = None
        if self.prior_scale:
            total = total + self.prior_scale * prior_vector_reconstruction(
                posterior, self.decoder, self.vector_keys, self.raw_keys, self.unimix
            )
        if self.vector_extra:
            vector_reco = vector_reconstruction(posterior, self.vector_keys, self.raw_keys)
            total = total + self.vector_extra * vector_reco
        elif self.vector_keys:  # a metric only
            with torch.no_grad():
                vector_reco = vector_reconstruction(posterior, self.vector_keys, self.raw_keys)
        if self.vector_extra or self.prior_scale:
            posterior = posterior.detach()
        return total, losses, posterior, vector_reco


def replay_value_loss(
    value_loss: DreamerV3ValueLoss, posterior: TensorDictBase, imagined: TensorDictBase, cfg: DictConfig
) -> torch.Tensor:
    """The critic's loss on the replayed sequences themselves (DreamerV3's ``repval``, ``algo.critic.replay_scale``):
    each posterior state's λ-return from the real rewards and episode ends that follow it in the sequence,
    bootstrapped from its first imagined return, so that the critic also learns what really followed — a death
    whose penalty the reward and continue heads still miss — and not only what imagination predicts.  The states
    carry no gradient into the world model (its optimiser is separate)."""
    nxt = posterior["next"]
    replay = TensorDict({k: nxt[k].detach().float() for k in LATENT}, posterior.shape)
    replay["bootstrap"] = imagined["lambda_target"][:, 0].detach().reshape(posterior.shape)
    replay["next", "reward"] = nxt["true_reward"].float()
    replay["next", "done"], replay["next", "terminated"] = nxt["done"], nxt["terminated"]
    return value_loss.replay_value_loss(replay, horizon=1 / (1 - cfg.gamma), lmbda=cfg.lmbda)["loss_replay_value"]


# ------------------------------------------------------------------------------------------------ diagnostics
def _masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    return x[mask].mean() if bool(mask.any()) else x.new_tensor(float("nan"))


@torch.no_grad()
def diagnostics(
    model: DreamerModel,
    critic: TensorDictSequential,
    posterior: TensorDictBase,
    imagined: TensorDictBase,
    return_scale: torch.Tensor,
) -> dict[str, torch.Tensor]:
    """What tells a collapsing DreamerV3 from a learning one, from one gradient step's replayed batch
    (``posterior``: the world model's outputs) and imagination (``imagined``):

    * ``reward_error_consume`` / ``reward_error_other``: the reward head's mean absolute error on the steps that ate
      or drank and on the others (``reward_true_consume`` / ``reward_pred_consume``: the true and predicted reward
      on those steps; ``consume_share``: how many of the batch's steps they are);
    * ``continue_terminal`` / ``continue_error_other``: the continue head's probability of going on where the
      episode ended (should be 0) and of stopping where it went on (should be 0);
    * ``critic_value``: the critic's value of the replayed states;
    * ``policy_<action>``: the actor's mean probability of each action on the replayed states;
    * ``advantage_<action>``: the normalised advantage (λ-return minus the critic's value, over the return scale)
      of imagination's first step, by the action taken: what the actor's REINFORCE gradient pushes each action by.
    """
    nxt = posterior["next"]
    error = (nxt["reward"] - nxt["true_reward"]).abs()
    event = nxt["consumed"]
    out = {
        "reward_error_consume": _masked_mean(error, event),
        "reward_error_other": _masked_mean(error, ~event),
        "reward_true_consume": _masked_mean(nxt["true_reward"], event),
        "reward_pred_consume": _masked_mean(nxt["reward"], event),
        "consume_share": event.float().mean(),
    }
    go_on = torch.sigmoid(nxt["continue_pred"].float())
    ended = nxt["terminated"]
    out["continue_terminal"] = _masked_mean(go_on, ended)
    out["continue_error_other"] = _masked_mean(1 - go_on, ~ended)
    latents = TensorDict({k: nxt[k].reshape(-1, nxt[k].shape[-1]).float() for k in LATENT}, [nxt.numel()])
    out["critic_value"] = critic(latents.clone())["state_value"].mean()
    probs = model.actor.get_dist(latents).probs.mean(0)
    first = imagined[:, 0]
    values = critic(first.select(*LATENT).clone())["state_value"]
    advantage = (first["lambda_target"] - values) / return_scale
    taken = first["action"].float()  # one-hot [N, actions]
    per_action = (taken * advantage).sum(0) / taken.sum(0).clamp_min(1)
    for i, name in enumerate(ACTION_NAMES):
        out[f"policy_{name}"] = probs[i]
        out[f"advantage_{name}"] = per_action[i] if bool(taken[:, i].any()) else per_action.new_tensor(float("nan"))
    return out
