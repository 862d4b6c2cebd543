"""DreamerV3 on TorchRL (``algo=dreamer``; its CPU size ``algo=dreamer_xs``), as the paper's sheeprl DreamerV3
baseline (SPEC §12; hyperparameters in conf/algo/dreamer*.yaml).

The algorithm's four functions (:class:`~evaaa_baselines.algos.Algorithm`) are exported here; the parts, in the
order a gradient step uses them:

* :mod:`.model` — the networks (multimodal encoder and decoder, torchrl's DreamerV3 RSSM, reward, continue, actor
  and critic heads) and their wiring into tensordict modules: the world model over replayed sequences, the
  imagination env, the acting and evaluation policies, the env transforms that carry the recurrent state;
* :mod:`.replay` — the sequence replay buffer, on disk or in memory;
* :mod:`.losses` — the world-model loss with its extra reconstruction terms, the critic's loss on replayed
  sequences, and the diagnostics a logged gradient step reports;
* :mod:`.update` — :class:`~.update.Learner`, the gradient step in three phases (world model, actor, critic),
  each replayable as a CUDA graph, with the optimisers and the slow critic (``algo.update``);
* :mod:`.openloop` — the open-loop prediction pictures written during training;
* :mod:`.loop` — :func:`train`, the training loop;
* :mod:`.probes` — offline probes of a finished run's checkpoint and replay (used by ``scripts/probe_dreamer.py``
  and ``scripts/fit_world_model.py``, never by training).
"""

from .loop import train
from .model import make_model, make_policy, make_transforms
from .update import check_config

__all__ = ["check_config", "make_model", "make_policy", "make_transforms", "train"]
