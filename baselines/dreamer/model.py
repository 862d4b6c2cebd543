"""DreamerV3's networks and their wiring (SPEC §12): a multimodal encoder and decoder, torchrl's DreamerV3 RSSM
(``RSSMPriorV3`` / ``RSSMPosteriorV3``), two-hot symlog reward and critic heads, a continue head and
``DreamerV3DiscreteActor``, all held by :class:`DreamerModel`; then the tensordict modules that share their
parameters: the world model over replayed sequences, the imagination env, the continue and value models, the acting
policy that carries its recurrent state from step to step, the evaluation policy, and the env transforms that state
needs.

Only the enabled observation keys are encoded and decoded: an ablation removes the key from both.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torch.nn import functional as F
from torchrl.data import Composite, OneHot, Unbounded
from torchrl.envs import InitTracker, TensorDictPrimer, Transform
from torchrl.envs.model_based.dreamer import DreamerEnv
from torchrl.modules import (
    DreamerV3DiscreteActor,
    DreamerV3ImageDecoder,
    DreamerV3ImageEncoder,
    DreamerV3MLP,
    DreamerV3SeededPolicy,
    RSSMPosteriorV3,
    RSSMPriorV3,
    RSSMRolloutV3,
    RSSMStateEstimatorV3,
    SymExpTwoHot,
    WorldModelWrapper,
)

from evaaa import ACTION_NAMES

from ..nets import symlog

NUM_ACTIONS = len(ACTION_NAMES)
LATENT = ("state", "belief")  # the stochastic sample z (flattened one-hots) and the GRU's deterministic state h


# ------------------------------------------------------------------------------------------------ networks
class DreamerEncoder(nn.Module):
    """Observation tensors, in ``obs_shapes`` order, to one embedding.

    ``pixels`` (uint8 ``[..., H, W, C]``) go through torchrl's ``DreamerV3ImageEncoder`` (stride-2 convolutions of
    ``cnn.depth × cnn.mults`` channels, RMS norm, SiLU; it scales to x/255 − 0.5 itself); the vector keys are
    symlog-ed, concatenated and go through one ``DreamerV3MLP`` (``mlp_layers`` × ``dense``), as sheeprl's MLP
    encoder. :attr:`out_features` is the embedding size.
    """

    def __init__(self, obs_shapes: Mapping[str, Sequence[int]], cfg: DictConfig):
        super().__init__()
        self.keys = tuple(obs_shapes)
        self.out_features = 0
        if "pixels" in obs_shapes:
            height, width, channels = obs_shapes["pixels"]
            self.cnn = DreamerV3ImageEncoder(
                in_channels=channels,
                depth=cfg.cnn.depth,
                mults=tuple(cfg.cnn.mults),
                kernel_size=cfg.cnn.kernel,
                norm_eps=cfg.norm_eps,
            )
            self.out_features += self.cnn.output_features((channels, height, width))
        vector_features = sum(shape[-1] for key, shape in obs_shapes.items() if key != "pixels")
        if vector_features:
            self.mlp = DreamerV3MLP(
                vector_features, None, depth=cfg.mlp_layers, num_cells=cfg.dense, norm_eps=cfg.norm_eps
            )
            self.out_features += cfg.dense

    def forward(self, *obs: torch.Tensor) -> torch.Tensor:
        features, vectors = [], []
        for key, x in zip(self.keys, obs, strict=True):
            if key == "pixels":
                features.append(self.cnn(x.movedim(-1, -3)))  # [..., H, W, C] -> [..., C, H, W]
            else:
                vectors.append(symlog(x))
        if vectors:
            features.append(self.mlp(torch.cat(vectors, dim=-1)))
        return torch.cat(features, dim=-1)


class DreamerDecoder(nn.Module):
    """The latent (``state``, ``belief``) to a reconstruction of every observation key, in ``obs_shapes`` order.

    ``pixels`` come from torchrl's ``DreamerV3ImageDecoder`` (mirroring the encoder) as ``[..., H, W, C]`` floats
    on the x/255 scale; the vector keys from one ``DreamerV3MLP`` trunk with a linear head per key, predicted in
    symlog space and returned raw (symexp), since ``DreamerV3ModelLoss`` compares the symlogs of prediction and
    target.
    """

    def __init__(self, obs_shapes: Mapping[str, Sequence[int]], latent: int, cfg: DictConfig):
        super().__init__()
        self.keys = tuple(obs_shapes)  # the keys reconstructed (the model leaves pixels out with decode_pixels=false)
        if "pixels" in obs_shapes:
            height, width, channels = obs_shapes["pixels"]
            self.cnn = DreamerV3ImageDecoder(
                latent,
                (channels, height, width),
                depth=cfg.cnn.depth,
                mults=tuple(cfg.cnn.mults),
                kernel_size=cfg.cnn.kernel,
                num_blocks=1,
                norm_eps=cfg.norm_eps,
            )
        vectors = {key: shape[-1] for key, shape in obs_shapes.items() if key != "pixels"}
        if vectors:
            self.mlp = DreamerV3MLP(latent, None, depth=cfg.mlp_layers, num_cells=cfg.dense, norm_eps=cfg.norm_eps)
            self.heads = nn.ModuleDict({key: nn.Linear(cfg.dense, size) for key, size in vectors.items()})

    def forward(self, state: torch.Tensor, belief: torch.Tensor) -> tuple[torch.Tensor, ...]:
        latent = torch.cat([state, belief], dim=-1)
        hidden = self.mlp(latent) if hasattr(self, "mlp") else None
        out = []
        for key in self.keys:
            if key == "pixels":
                out.append(self.cnn(latent).movedim(-3, -1))
            else:
                out.append(self._symexp(self.heads[key](hidden)))
        return tuple(out)

    def vector(self, key: str, state: torch.Tensor, belief: torch.Tensor) -> torch.Tensor:
        """One vector key's reconstruction alone (raw units), without decoding the pixels."""
        return self.vectors(state, belief, (key,))[key]

    def vectors(
        self, state: torch.Tensor, belief: torch.Tensor, keys: Sequence[str] | None = None
    ) -> dict[str, torch.Tensor]:
        """The vector keys' reconstructions (raw units; all of them by default), without decoding the pixels."""
        hidden = self.mlp(torch.cat([state, belief], dim=-1))
        return {key: self._symexp(self.heads[key](hidden)) for key in (self.heads if keys is None else keys)}

    @staticmethod
    def _symexp(y: torch.Tensor) -> torch.Tensor:
        return torch.sign(y) * torch.expm1(y.abs())


class DreamerModel(nn.Module):
    """Every trained network of DreamerV3: world model (encoder, RSSM prior and posterior, decoder, reward and
    continue heads), actor and critic.  Plain modules; :func:`world_model`, :func:`imagination_env`,
    :func:`acting_policy` wire them into tensordict modules that share their parameters."""

    def __init__(self, cfg: DictConfig, obs_shapes: Mapping[str, Sequence[int]]):
        super().__init__()
        m = cfg.model
        self.obs_keys = tuple(obs_shapes)
        self.state_dim = m.stochastic * m.classes
        self.belief_dim = m.recurrent
        latent = self.state_dim + self.belief_dim
        self.encoder = DreamerEncoder(obs_shapes, m)
        self.prior = RSSMPriorV3(
            action_shape=(NUM_ACTIONS,),
            action_dim=NUM_ACTIONS,
            hidden_dim=m.hidden,
            rnn_hidden_dim=m.recurrent,
            num_categoricals=m.stochastic,
            num_classes=m.classes,
            recurrent_model=m.recurrent_model,
            norm_eps=m.norm_eps,
            unimix=m.unimix,
        )
        self.posterior = RSSMPosteriorV3(
            hidden_dim=m.hidden,
            num_categoricals=m.stochastic,
            num_classes=m.classes,
            rnn_hidden_dim=m.recurrent,
            obs_embed_dim=self.encoder.out_features,
            use_rms_norm=True,
            norm_eps=m.norm_eps,
            unimix=m.unimix,
        )
        decoded = {k: v for k, v in obs_shapes.items() if k != "pixels" or decode_pixels(cfg)}
        if not decoded:
            raise ValueError(
                "algo.world_model.decode_pixels=false needs a vector observation key to reconstruct, and this run "
                f"observes only {list(obs_shapes)}: keep decode_pixels=true or enable a vector modality"
            )
        self.decoder = DreamerDecoder(decoded, latent, m)
        # reward and critic: two-hot over symexp-spaced bins, zero-initialised outputs (DreamerV3's outscale 0)
        self.reward = DreamerV3MLP(
            latent, m.bins, depth=m.mlp_layers, num_cells=m.dense, outscale=0.0, norm_eps=m.norm_eps
        )
        self.two_hot = SymExpTwoHot(m.bins)
        self.cont = DreamerV3MLP(latent, 1, depth=m.mlp_layers, num_cells=m.dense, norm_eps=m.norm_eps)
        self.actor = DreamerV3DiscreteActor(
            latent, NUM_ACTIONS, depth=m.mlp_layers, num_cells=m.dense, norm_eps=m.norm_eps, unimix=m.unimix
        )
        self.value = DreamerV3MLP(
            latent, m.bins, depth=m.mlp_layers, num_cells=m.dense, outscale=0.0, norm_eps=m.norm_eps
        )

    def world_model_parameters(self) -> list[nn.Parameter]:
        return [
            p
            for name in ("encoder", "prior", "posterior", "decoder", "reward", "cont")
            for p in getattr(self, name).parameters()
        ]


def decode_pixels(cfg: DictConfig) -> bool:
    """Whether the world model reconstructs the pixels (``algo.world_model.decode_pixels``, DreamerV3's true).  False
    keeps the pixels in the encoder and leaves them out of the decoder and its loss: the latent learns from the
    pixels only what helps predict the vector keys, the reward and the episode's end."""
    return bool(cfg.world_model.get("decode_pixels", True))


def make_model(cfg: DictConfig, obs_shapes: Mapping[str, Sequence[int]]) -> DreamerModel:
    return DreamerModel(cfg, obs_shapes)


# ------------------------------------------------------------------------------------------------ wiring
def next_keys(*keys: str) -> list[tuple[str, str]]:
    """The ``("next", key)`` entries of ``keys``: what a step leads to."""
    return [("next", k) for k in keys]


def one_hot_action(action: torch.Tensor) -> torch.Tensor:
    """The action as a one-hot float vector over the five actions."""
    return F.one_hot(action, NUM_ACTIONS).float()


def world_model(model: DreamerModel) -> TensorDictSequential:
    """Replayed sequences ``[batch, time]`` (``action``, ``is_init``, ``("next", <obs>)``, zero initial latent) to
    what ``DreamerV3ModelLoss`` reads under ``"next"``: prior and posterior logits, posterior latent,
    reconstructions ``reco_<key>``, reward logits and value, continue logit.  The RSSM restarts from zeros where
    ``is_init`` marks an episode's first step (``RSSMRolloutV3``)."""
    keys = model.obs_keys
    rollout = RSSMRolloutV3(
        TensorDictModule(
            model.prior,
            in_keys=["state", "belief", "action_onehot"],
            out_keys=next_keys("prior_logits", "state", "belief"),
        ),
        TensorDictModule(
            model.posterior,
            in_keys=next_keys("belief", "encoded_latents"),
            out_keys=next_keys("posterior_logits", "state"),
        ),
        reset_key="is_init",
    )
    return TensorDictSequential(
        TensorDictModule(one_hot_action, in_keys=["action"], out_keys=["action_onehot"]),
        TensorDictModule(model.encoder, in_keys=next_keys(*keys), out_keys=next_keys("encoded_latents")),
        rollout,
        TensorDictModule(
            model.decoder, in_keys=next_keys(*LATENT), out_keys=next_keys(*(f"reco_{k}" for k in model.decoder.keys))
        ),
        TensorDictModule(model.reward, in_keys=next_keys(*LATENT), out_keys=next_keys("reward_logits")),
        TensorDictModule(model.two_hot, in_keys=next_keys("reward_logits"), out_keys=next_keys("reward")),
        TensorDictModule(model.cont, in_keys=next_keys(*LATENT), out_keys=next_keys("continue_pred")),
    )


def imagination_env(model: DreamerModel, device: torch.device | str = "cpu") -> DreamerEnv:
    """torchrl's ``DreamerEnv`` on the prior and the reward head: the latent world the actor is trained in, on the
    device the model is on."""
    transition = TensorDictModule(model.prior, in_keys=["state", "belief", "action"], out_keys=["_", *LATENT])
    reward = TensorDictSequential(
        TensorDictModule(model.reward, in_keys=list(LATENT), out_keys=["reward_logits"]),
        TensorDictModule(model.two_hot, in_keys=["reward_logits"], out_keys=["reward"]),
    )
    env = DreamerEnv(
        WorldModelWrapper(transition, reward),
        prior_shape=(model.state_dim,),
        belief_shape=(model.belief_dim,),
        device=device,
    )
    env.observation_spec = Composite(
        state=Unbounded(model.state_dim, device=device),
        belief=Unbounded(model.belief_dim, device=device),
        device=device,
    )
    env.state_spec = env.observation_spec.clone()
    env.action_spec = OneHot(NUM_ACTIONS, device=device)
    env.reward_spec = Unbounded((1,), device=device)
    return env


def continuation_model(model: DreamerModel) -> TensorDictSequential:
    """The continue head as a probability, for the discounts of imagined returns."""
    return TensorDictSequential(
        TensorDictModule(model.cont, in_keys=list(LATENT), out_keys=["continue_logits"]),
        TensorDictModule(torch.sigmoid, in_keys=["continue_logits"], out_keys=["continuation"]),
    )


def value_model(model: DreamerModel) -> TensorDictSequential:
    return TensorDictSequential(
        TensorDictModule(model.value, in_keys=list(LATENT), out_keys=["state_value_logits"]),
        TensorDictModule(model.two_hot, in_keys=["state_value_logits"], out_keys=["state_value"]),
    )


def prefill_policy(td: TensorDictBase) -> TensorDictBase:
    """Uniform random actions (and the matching ``prev_action``), as sheeprl's DreamerV3 fills its buffer before the
    first gradient step: the untrained networks would act about as randomly, at the cost of a forward pass per step
    (with size S on a CPU, most of the prefill's time).  The carried latent stays zero until the policy takes over."""
    action = torch.randint(NUM_ACTIONS, td.batch_size)
    td["action"], td["prev_action"] = action, one_hot_action(action)
    return td


def _carry(action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    # the one-hot is the next step's previous action; the env takes its index
    return action.float(), action.argmax(-1)


def acting_policy(model: DreamerModel) -> TensorDictSequential:
    """Observations and the carried latent to ``"action"``: encode, one RSSM filtering step
    (``RSSMStateEstimatorV3``, which zeroes the latent where ``is_init``), the actor.  The updated ``state`` /
    ``belief`` and ``prev_action`` are written in place; the primer of :func:`make_transforms` carries them into the
    next step and zeroes them at a reset."""
    return TensorDictSequential(
        TensorDictModule(model.encoder, in_keys=list(model.obs_keys), out_keys=["embed"]),
        RSSMStateEstimatorV3(
            model.prior, model.posterior, in_keys=[*LATENT, "prev_action", "embed", "is_init"], out_keys=list(LATENT)
        ),
        model.actor,
        TensorDictModule(_carry, in_keys=["action"], out_keys=["prev_action", "action"]),
    )


class _EvaluationPolicy(TensorDictModuleBase):
    """The acting policy on its own random stream (torchrl's ``DreamerV3SeededPolicy``), restarted whenever every
    world starts an episode: an evaluation from a reset depends on the weights and the worlds' seed alone, and draws
    nothing from the training RNGs (the RSSM samples its latent even when the actor takes its mode)."""

    def __init__(self, policy: TensorDictModuleBase, seed: int = 0):
        super().__init__()
        self.seeded = DreamerV3SeededPolicy(policy, seed)
        self.in_keys, self.out_keys = policy.in_keys, policy.out_keys

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        if bool(td["is_init"].all()):
            self.seeded.reset_counter()
        return self.seeded(td)


def make_policy(model: DreamerModel) -> TensorDictModuleBase:
    """The policy evaluations and ``load_policy`` use (deterministic: the actor's mode, under
    ``ExplorationType.DETERMINISTIC``)."""
    return _EvaluationPolicy(acting_policy(model))


def make_transforms(cfg: DictConfig, obs_keys: Sequence[str], model: DreamerModel) -> list[Transform]:
    """Episode-start flags and the carried latent and previous action, zeroed at every reset."""
    return [
        InitTracker(),
        TensorDictPrimer(
            random=False,
            default_value=0.0,
            expand_specs=True,
            state=Unbounded(model.state_dim),
            belief=Unbounded(model.belief_dim),
            prev_action=Unbounded(NUM_ACTIONS),
        ),
    ]
