"""Where the baselines' files are: the Hydra configs (``conf/``, beside the package in the repository)."""

from __future__ import annotations

from pathlib import Path

#: conf/: config.yaml and its groups (algo, level, modality, reward, logger, preset, protocol)
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"
