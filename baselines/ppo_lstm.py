"""PPO+LSTM (``algo=ppo_lstm``): the code of :mod:`.ppo`; conf/algo/ppo_lstm.yaml adds the LSTM (``algo.lstm``) and
the sequence minibatches, which that module builds when its config asks for them."""

from .ppo import check_config, make_model, make_policy, make_transforms, train

__all__ = ["check_config", "make_model", "make_policy", "make_transforms", "train"]
