"""Network pieces the baselines share: the multimodal observation encoder and the MLP heads.

Plain torch modules over tensors, built from torchrl's ``ConvNet`` and ``MLP``; each algorithm's file wires them
into tensordict modules.  Sizes come from the algorithm's config (``encoder``, ``head``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import nn
from torchrl.modules import MLP, ConvNet


def symlog(x: torch.Tensor) -> torch.Tensor:
    """sign(x)·log(1 + |x|): raw EVs (±15, damage to 100), temperatures and odour sums on one gentle scale."""
    return torch.sign(x) * torch.log1p(x.abs())


def stacked_shapes(obs_shapes: Mapping[str, Sequence[int]], keys: Sequence[str], frames: int) -> dict[str, tuple]:
    """Shapes after ``CatFrames(N=frames, dim=-1)`` on ``keys``: the last axis grows ``frames`` times."""
    return {k: (*s[:-1], s[-1] * frames) if k in keys else tuple(s) for k, s in obs_shapes.items()}


class MultimodalEncoder(nn.Module):
    """Observation tensors, in ``obs_shapes`` order, to one feature vector.

    ``pixels`` (uint8 ``[..., H, W, C]``, frames stacked on C) are scaled to x/255 − 0.5 and go through a CNN and a
    linear layer to ``cnn.features``; every vector key goes through symlog and its own one-layer MLP of
    ``mlp[key]`` units, or ``mlp_default`` units for a key ``mlp`` does not list (a sense of one's own trains
    without a config edit).  The features are concatenated; :attr:`out_features` is their size.
    """

    def __init__(
        self,
        obs_shapes: Mapping[str, Sequence[int]],
        cnn: Mapping,
        mlp: Mapping[str, int],
        mlp_default: int | None = None,
    ):
        super().__init__()
        self.keys = tuple(obs_shapes)
        self.branches = nn.ModuleDict()
        self.out_features = 0
        for key, shape in obs_shapes.items():
            if key == "pixels":
                height, width, channels = shape
                conv = ConvNet(
                    in_features=channels,
                    num_cells=list(cnn["channels"]),
                    kernel_sizes=list(cnn["kernels"]),
                    strides=list(cnn["strides"]),
                    paddings=cnn["padding"],
                    activation_class=nn.ReLU,
                )
                with torch.no_grad():
                    flat = conv(torch.zeros(1, channels, height, width)).shape[-1]
                self.branches[key] = nn.Sequential(conv, nn.Linear(flat, cnn["features"]), nn.ReLU())
                self.out_features += cnn["features"]
            else:
                units = mlp.get(key, mlp_default)
                if units is None:
                    raise ValueError(
                        f"observation key {key!r} has no MLP width: set algo.encoder.mlp.{key} or "
                        f"algo.encoder.mlp_default (listed: {', '.join(mlp)})"
                    )
                self.branches[key] = nn.Sequential(nn.Linear(shape[-1], units), nn.ReLU())
                self.out_features += units

    def forward(self, *obs: torch.Tensor) -> torch.Tensor:
        features = []
        for key, x in zip(self.keys, obs, strict=True):
            if key == "pixels":
                # in place on the fresh float copy: these are the largest tensors of an update
                x = x.to(torch.float32).mul_(1 / 255).sub_(0.5).movedim(-1, -3)  # [..., H, W, C] -> [..., C, H, W]
            else:
                x = symlog(x)
            features.append(self.branches[key](x))
        return torch.cat(features, dim=-1)


def head(in_features: int, units: Sequence[int], out_features: int, layer_norm: bool = False) -> MLP:
    """An MLP head: ReLU hidden layers of ``units`` (each followed by LayerNorm if asked), then a linear output."""
    norm = {"norm_class": nn.LayerNorm, "norm_kwargs": [{"normalized_shape": u} for u in units]} if layer_norm else {}
    return MLP(
        in_features=in_features, out_features=out_features, num_cells=list(units), activation_class=nn.ReLU, **norm
    )


def compile_networks(model: nn.Module, types: tuple[type, ...] = (MultimodalEncoder, MLP)) -> int:
    """``compile=true``: ``torch.compile`` in place (``nn.Module.compile``, so parameter names do not change) every
    outermost submodule of ``types`` — the plain-torch networks; the tensordict wiring around them stays eager.
    Returns how many were compiled."""
    count = 0
    for child in model.children():
        if isinstance(child, types):
            child.compile(dynamic=False)  # a few fixed shapes (acting, minibatch); dynamic ones failed in inductor
            count += 1
        else:
            count += compile_networks(child, types)
    return count
