"""A stage's CSV logs (evaaa_baselines.logs): the columns ``eval.csv`` goes on with, an ended episode's row and
scalars, rows written and cut back to a checkpoint's size, counters through a checkpoint.  (The scalar log's packing:
tests/test_scalar_log.py; a refused disk: tests/test_hostile_files.py.)"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from evaaa.records import TRAINING_EPISODE_FIELDS
from evaaa_baselines.logs import (
    EVAL_COLUMNS,
    EVAL_COLUMNS_BEFORE_CPU,
    Counters,
    CsvLog,
    episode_metrics,
    episode_row,
    eval_columns,
)


def test_eval_csv_goes_on_with_its_own_columns(tmp_path):
    path = tmp_path / "eval.csv"
    assert eval_columns(path) == EVAL_COLUMNS  # no file yet
    path.write_text(",".join(EVAL_COLUMNS_BEFORE_CPU) + "\n")
    assert eval_columns(path) == EVAL_COLUMNS_BEFORE_CPU  # begun before cpu_seconds: goes on without it
    assert eval_columns(path, fresh=True) == EVAL_COLUMNS  # a file begun empty
    path.write_text("env_steps,episodes,survival_mean\n")  # one row per evaluation: an earlier evaaa's
    with pytest.raises(ValueError, match="holds one row per evaluation"):
        eval_columns(path)


def test_an_ended_episode_s_row_and_scalars():
    # world 1 of 2 ended by hunger after 37 steps, returning -4.5
    info = {
        "step_count": torch.tensor([5, 37]),
        "end_type": torch.tensor([0, 2]),
        "satiation": torch.tensor([0.0, -1.25]),
        "hydration": torch.tensor([0.0, 0.5]),
        "temperature": torch.tensor([0.0, 0.25]),
        "damage": torch.tensor([0.0, 3.0]),
    }
    nxt = TensorDict({"info": info, "episode_reward": torch.tensor([[0.0], [-4.5]])}, batch_size=[2])
    row = episode_row(nxt, 1, env_steps=96, stage=0, level="1-1", episode=7)
    assert set(row) == set(TRAINING_EPISODE_FIELDS)
    assert {k: v for k, v in row.items() if k != "wall_time"} == {
        "env_steps": 96,
        "stage": 0,
        "level": "1-1",
        "episode": 7,
        "world": 1,
        "steps": 37,
        "return": -4.5,
        "end_type": "FoodOutOfRange",
        "final_satiation": -1.25,
        "final_hydration": 0.5,
        "final_temperature": 0.25,
        "final_damage": 3.0,
    }
    assert episode_metrics(row) == {
        "episode/survival_steps": 37,
        "episode/return": -4.5,
        "episode/satiation": -1.25,
        "episode/hydration": 0.5,
        "episode/temperature": 0.25,
        "episode/damage": 3.0,
        "episode/end/ResourceConsumed": 0.0,
        "episode/end/FoodOutOfRange": 1.0,
        "episode/end/WaterOutOfRange": 0.0,
        "episode/end/TemperatureOutOfRange": 0.0,
        "episode/end/DamageTooHigh": 0.0,
        "episode/end/MaxStepReached": 0.0,
    }


def test_rows_are_appended_and_cut_back_to_a_checkpoint_s_size(tmp_path):
    path = tmp_path / "log.csv"
    log = CsvLog(path, ["step", "value"])
    log.write({"step": 1, "value": 1 / 3, "ignored": "x"})
    at_checkpoint = log.size()
    log.write({"step": 2, "value": 2.5})
    log.close()
    assert path.read_bytes() == b"step,value\r\n1,0.333333\r\n2,2.5\r\n"  # floats to 6 significant digits
    resumed = CsvLog(path, ["step", "value"], truncate_to=at_checkpoint)
    resumed.write({"step": 2, "value": 7})
    resumed.close()
    assert path.read_bytes() == b"step,value\r\n1,0.333333\r\n2,7\r\n"  # one header, the lost row written again


def test_counters_go_through_a_checkpoint():
    counters = Counters(steps=96, episodes=3)
    restored = Counters(steps=0, episodes=0, logged=0)
    restored.load_state_dict(counters.state_dict())
    assert restored == {"steps": 96, "episodes": 3, "logged": 0}
