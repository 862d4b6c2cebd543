"""DreamerV3 does exactly what a recording made before a change did (``tests/dreamer_reference.py``: seeded debug
runs of ``dreamer``, ``dreamer_xs`` and every optional loss path, acting trajectories, probe results), and the
comparison finds a changed weight, optimiser moment, CSV row, acting step or probe value while it ignores wall-clock
time.

The recording depends on the machine's CPU kernels, so the reference is one made on this machine before the change:

    python tests/dreamer_reference.py record /tmp/before      # on the code before the change
    EVAAA_DREAMER_REFERENCE=/tmp/before pytest -n 0 tests/test_dreamer_reference.py
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import dreamer_reference
import pytest
import torch

from evaaa_baselines.checkpoint import save_checkpoint

REFERENCE = os.environ.get("EVAAA_DREAMER_REFERENCE")


@pytest.mark.skipif(not REFERENCE, reason="EVAAA_DREAMER_REFERENCE names no recording made before the change")
def test_dreamer_trains_acts_and_probes_exactly_as_the_recording(tmp_path):
    dreamer_reference.record(tmp_path / "now")
    assert dreamer_reference.compare(Path(REFERENCE), tmp_path / "now") == []


def fake_recording(
    root: Path,
    weight: float = 1.0,
    moment: float = 0.5,
    ret: str = "-0.12",
    action: int = 3,
    error: float = 0.25,
    seconds: float = 1.0,
    wall_time: str = "2026-11-27T16:10:08",
) -> Path:
    """A recording of the shape :func:`dreamer_reference.record` writes, small enough to build in a test."""
    for name in dreamer_reference.RUNS:
        run = root / name
        (run / "openloop").mkdir(parents=True)
        state = {
            "model": {"encoder.weight": torch.tensor([weight, 2.0])},
            "components": {"optimizer_world_model": {"state": {0: {"exp_avg": torch.tensor([moment])}}}},
            "time": {"seconds": seconds},
        }
        save_checkpoint(state, run / "checkpoint.pt")
        (run / "episodes.csv").write_text(f"env_steps,return,wall_time\n96,{ret},{wall_time}\n")
        (run / "openloop" / "openloop-0-1-1-000000032.png").write_bytes(b"\x89PNG fake")
    torch.save({"loaded_deterministic": {"action": torch.tensor([action, 1])}}, root / "trajectories.pt")
    (root / "probes.json").write_text(
        json.dumps(
            {"ev_decoding_errors": {"eating": {"satiation": error}}, "eat_success_readout": {"auc": float("nan")}}
        )
    )
    return root


@pytest.mark.parametrize(
    ("change", "found"),
    [
        ({"weight": 1.0 + 1e-7}, "dreamer/checkpoint.pt.model.encoder.weight: tensors differ"),
        ({"moment": 0.25}, "dreamer/checkpoint.pt.components.optimizer_world_model.state.0.exp_avg: tensors differ"),
        ({"ret": "-0.13"}, "dreamer/episodes.csv: rows differ"),
        ({"action": 2}, "trajectories.loaded_deterministic.action: tensors differ"),
        ({"error": 0.26}, "probes.ev_decoding_errors.eating.satiation: 0.25 != 0.26"),
    ],
)
def test_the_comparison_finds_each_kind_of_difference(tmp_path, change, found):
    reference = fake_recording(tmp_path / "a")
    assert dreamer_reference.compare(reference, fake_recording(tmp_path / "b")) == []  # NaN equals NaN here
    assert found in dreamer_reference.compare(reference, fake_recording(tmp_path / "c", **change))


def test_the_comparison_ignores_wall_clock_time_but_not_a_missing_picture(tmp_path):
    reference = fake_recording(tmp_path / "a")
    later = fake_recording(tmp_path / "b", seconds=9.0, wall_time="2026-11-28T09:00:00")
    assert dreamer_reference.compare(reference, later) == []
    shutil.rmtree(later / "dreamer_xs" / "openloop")
    assert any(d.startswith("dreamer_xs: files differ") for d in dreamer_reference.compare(reference, later))
