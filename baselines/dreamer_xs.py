"""DreamerV3-XS (``algo=dreamer_xs``): the code of :mod:`.dreamer`, with the smaller networks and the settings of
conf/algo/dreamer_xs.yaml."""

from .dreamer import check_config, make_model, make_policy, make_transforms, train

__all__ = ["check_config", "make_model", "make_policy", "make_transforms", "train"]
