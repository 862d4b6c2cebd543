"""Episode records and their summaries: rows match what happened, files append safely, numbers are right."""

from __future__ import annotations

import csv

import numpy as np
import pandas as pd
import pytest

from evaaa.physiology import END_TYPES
from evaaa.records import EPISODE_FIELDS, EpisodeTracker, append_rows, read_rows
from evaaa_baselines.reports import (
    markdown_table,
    outcome,
    plot_outcomes,
    plot_summary,
    read_episodes,
    short_labels,
    summarize,
)
from evaaa_baselines.reports.stats import interval


def info(n, *, step, end=0, food=0, water=0, collision=False, damage=0.0, success=False, near_heat=False):
    def col(value, dtype):
        return np.full((n, 1), value, dtype=dtype)

    return {
        "food_eaten": col(food, np.int64),
        "water_eaten": col(water, np.int64),
        "collision": col(collision, bool),
        "damage_taken": col(damage, np.float32),
        "attacked": col(False, bool),
        "step_count": col(step, np.int64),
        "end_type": col(end, np.int64),
        "success": col(success, bool),
        "trigger_crossed": col(False, bool),
        "near_heat": col(near_heat, bool),
        "satiation": col(-1.0, np.float32),
        "hydration": col(2.0, np.float32),
        "temperature": col(0.5, np.float32),
        "damage": col(3.0, np.float32),
    }


def test_tracker_sums_an_episode_and_starts_over():
    tracker = EpisodeTracker(2, "two-resource-food", "oracle", seed=3)
    assert tracker.update([1.0, 1.0], info(2, step=1, collision=True, damage=2.0, near_heat=True), [False, False]) == []
    done = info(2, step=2, food=1, end=END_TYPES.index("ResourceConsumed"), success=True)
    rows = tracker.update([0.5, 0.5], done, [True, False])
    assert len(rows) == 1
    row = rows[0]
    assert row["steps"] == 2 and row["return"] == pytest.approx(1.5) and row["food_eaten"] == 1
    assert row["collisions"] == 1 and row["damage_taken"] == pytest.approx(2.0) and row["steps_near_heat"] == 1
    assert row["end_type"] == "ResourceConsumed" and row["success"] is True and row["seed"] == 3
    assert row["final_damage"] == pytest.approx(3.0)
    # world 0 starts over from zero, world 1 keeps counting
    rows = tracker.update([2.0, 2.0], info(2, step=3, end=END_TYPES.index("MaxStepReached")), [True, True])
    assert [r["return"] for r in rows] == pytest.approx([2.0, 3.5])
    assert [r["episode"] for r in rows] == [1, 2]


def test_training_levels_are_not_judged():
    tracker = EpisodeTracker(1, "1-1", "random")
    rows = tracker.update([0.0], info(1, step=9, end=END_TYPES.index("FoodOutOfRange"), success=False), [True])
    assert rows[0]["success"] == ""


def test_append_rows_writes_the_header_once_and_refuses_other_columns(tmp_path):
    path = tmp_path / "runs" / "episodes.csv"
    tracker = EpisodeTracker(1, "two-resource-water", "random")
    row = tracker.update([0.0], info(1, step=4, end=1, water=1, success=True), [True])[0]
    append_rows(path, [row])
    append_rows(path, [row, row])
    rows = read_rows(path)
    assert len(rows) == 3 and list(rows[0])[: len(EPISODE_FIELDS)] == list(EPISODE_FIELDS)
    bad = dict(row, extra_column=1)
    with pytest.raises(ValueError):
        append_rows(path, [bad])
    assert len(read_rows(path)) == 3


def test_summary_numbers_match_the_inputs(tmp_path):
    rows = pd.DataFrame(
        {
            "level": ["two-resource-food"] * 4 + ["1-1"] * 3,
            "policy": ["a", "a", "a", "a", "a", "a", "a"],
            "success": [True, False, True, True, np.nan, np.nan, np.nan],
            "steps": [10, 20, 30, 40, 100, 200, 600],
            "collisions": [0, 1, 2, 3, 0, 0, 0],
            "end_type": ["ResourceConsumed"] * 4 + ["FoodOutOfRange"] * 3,
            "food_eaten": [1, 0, 1, 1, 0, 0, 0],
        }
    )
    summary = summarize(rows).set_index("level")
    # Wilson score interval of 3 successes in 4, by its formula
    k, n, z = 3, 4, 1.959963984540054
    centre, half = (
        (k / n + z * z / (2 * n)) / (1 + z * z / n),
        z / (1 + z * z / n) * np.sqrt(k / n * (1 - k / n) / n + z * z / (4 * n * n)),
    )
    assert summary.loc["two-resource-food", "success_rate"] == pytest.approx(0.75)
    assert (
        summary.loc["two-resource-food", "success_low"],
        summary.loc["two-resource-food", "success_high"],
    ) == pytest.approx((centre - half, centre + half))
    # interquartile mean of 100, 200, 600: a quarter of 3 rounds down to none cut, so all three
    assert summary.loc["1-1", "survival_iqm"] == pytest.approx(300.0)
    assert summary.loc["1-1", "survival_mean"] == pytest.approx(300.0)
    assert summary.loc["1-1", "survival_se"] == pytest.approx(np.std([100, 200, 600], ddof=1) / np.sqrt(3))
    low, high = summary.loc["1-1", "survival_low"], summary.loc["1-1", "survival_high"]
    # one policy's episodes are its units: each episode a stratum of one
    assert (low, high) == (interval([[100.0], [200.0], [600.0]]).low, interval([[100.0], [200.0], [600.0]]).high)
    assert 100 <= low < 300 < high <= 600
    assert np.isnan(summary.loc["1-1", "success_rate"])
    table = markdown_table(summarize(rows))
    assert (
        f"| two-resource-food | 75.0% [{100 * (centre - half):.1f}, {100 * (centre + half):.1f}] (n=4 ep.) |" in table
    )
    assert f"| 1-1 | 300.0 [{low:.1f}, {high:.1f}]; 300.0 ± 152.8 (n=3 ep.) |" in table
    assert [outcome(r) for _, r in rows.iloc[:2].iterrows()] == ["success", "drank water (wrong)"]


def test_summary_survival_is_the_interquartile_mean_and_rates_are_never_plus_minus_zero():
    # 8 episodes: the IQM drops 2 at each end and averages 30, 40, 50, 60; an outlier does not move it
    rows = pd.DataFrame(
        {
            "level": ["1-1"] * 8 + ["y-maze"] * 5,
            "policy": ["a"] * 13,
            "success": [np.nan] * 8 + [False] * 5,
            "steps": [10, 20, 30, 40, 50, 60, 70, 5000] + [9] * 5,
            "collisions": [0] * 13,
            "end_type": ["FoodOutOfRange"] * 13,
            "food_eaten": [0] * 13,
        }
    )
    summary = summarize(rows).set_index("level")
    assert summary.loc["1-1", "survival_iqm"] == pytest.approx(45.0)
    assert summary.loc["1-1", "survival_mean"] == pytest.approx(660.0)
    assert summary.loc["y-maze", "success_rate"] == 0 and summary.loc["y-maze", "success_low"] == 0
    z2 = 1.959963984540054**2
    assert summary.loc["y-maze", "success_high"] == pytest.approx(z2 / (5 + z2))  # Wilson's upper end at 0 of n
    assert "| y-maze | 0.0% [0.0, 43.4] (n=5 ep.) |" in markdown_table(summarize(rows))


def test_read_episodes_parses_success(tmp_path):
    path = tmp_path / "e.csv"
    tracker = EpisodeTracker(1, "two-resource-food", "x")
    append_rows(path, tracker.update([0.0], info(1, step=2, end=1, food=1, success=True), [True]))
    tracker = EpisodeTracker(1, "1-1", "x")
    append_rows(path, tracker.update([0.0], info(1, step=2, end=2), [True]))
    rows = read_episodes([path])
    assert rows["success"].iloc[0] is True or rows["success"].iloc[0] == 1.0
    assert np.isnan(rows["success"].iloc[1])


def test_how_a_checkpoint_acted_is_recorded_and_kept_apart(tmp_path):
    path = tmp_path / "e.csv"
    for acting, step in (("mode", 100), ("sample", 700), ("sample", 900)):
        tracker = EpisodeTracker(1, "1-1", "run/model-0-1-1.pt", acting=acting)
        append_rows(path, tracker.update([0.0], info(1, step=step, end=2), [True]))
    append_rows(path, EpisodeTracker(1, "1-1", "random").update([0.0], info(1, step=50, end=2), [True]))
    rows = read_episodes([path])
    assert list(rows["acting"]) == ["mode", "sample", "sample", ""]
    summary = summarize(rows).set_index("policy")
    assert summary.loc["run/model-0-1-1.pt [sample]", "survival_mean"] == pytest.approx(800.0)
    assert summary.loc["run/model-0-1-1.pt [mode]", "survival_iqm"] == pytest.approx(100.0)
    assert summary.loc["random", "episodes"] == 1


def test_episode_files_from_before_the_acting_column_still_read(tmp_path):
    path = tmp_path / "old.csv"
    tracker = EpisodeTracker(1, "1-1", "random")
    row = tracker.update([0.0], info(1, step=7, end=2), [True])[0]
    row.pop("acting")
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(row))
        writer.writeheader()
        writer.writerow(row)
    rows = read_episodes([path])
    assert list(rows["acting"]) == [""] and summarize(rows)["policy"].tolist() == ["random"]


def test_figures_label_checkpoints_by_what_differs_in_their_paths(tmp_path, monkeypatch):
    a, b = "runs/1-1/ppo/all-squared/seed0/model-0-1-1.pt", "runs/1-1/dqn/all-squared/seed0/model-0-1-1.pt"
    names, note = short_labels(["oracle", a, f"{b} [mode+epsilon=0.05]", b])
    assert names == {"oracle": "oracle", a: "ppo", f"{b} [mode+epsilon=0.05]": "dqn [mode+epsilon=0.05]", b: "dqn"}
    assert note == "checkpoints: runs/1-1/<label>/all-squared/seed0/model-0-1-1.pt"
    one, note = short_labels(["random", a])
    assert one[a] == "seed0/model-0-1-1.pt" and note == f"seed0/model-0-1-1.pt: {a}"
    assert short_labels(["random", "human"]) == ({"random": "random", "human": "human"}, "")

    import matplotlib.figure

    shown: list[str] = []
    real_savefig = matplotlib.figure.Figure.savefig

    def savefig(fig, *args, **kwargs):  # every text the figure draws: legends, tick labels, titles
        shown.extend(t.get_text() for t in fig.findobj(matplotlib.text.Text))
        return real_savefig(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    rows = pd.DataFrame(
        {
            "level": ["two-resource-food"] * 3,
            "policy": [a, b, "random"],
            "success": [True, False, True],
            "steps": [10, 20, 30],
            "collisions": [0, 1, 2],
            "end_type": ["ResourceConsumed"] * 3,
            "food_eaten": [1, 0, 1],
            "water_eaten": [0, 1, 0],
        }
    )
    plot_summary(summarize(rows), tmp_path / "s.png", success=True, title="t")
    plot_outcomes(rows, tmp_path / "o.png")
    assert {"ppo", "dqn", "random"} <= set(shown)
    assert not any(a in t or b in t for t in shown if not t.startswith("checkpoints: ") and "\n" not in t)
    assert any("checkpoints: runs/1-1/<label>/all-squared/seed0/model-0-1-1.pt" in t for t in shown)


def test_summary_of_human_play_has_the_participants_as_units():
    # p01 survived 10, 20, 30 decisions, p02 1000 and 40: the participants are the units, mean ± se over the five
    # episodes, the IQM (one cut at each end of 10, 20, 30, 40, 1000) is the mean of 20, 30, 40; two participants
    # are too few for an interval
    rows = pd.DataFrame(
        {
            "level": ["1-1"] * 5,
            "policy": ["human"] * 5,
            "participant": ["p01"] * 3 + ["p02"] * 2,
            "success": [np.nan] * 5,
            "steps": [10, 20, 30, 1000, 40],
            "collisions": [0] * 5,
            "end_type": ["FoodOutOfRange"] * 5,
            "food_eaten": [0] * 5,
        }
    )
    row = summarize(rows).iloc[0]
    assert (row["units"], row["unit"], row["episodes"]) == (2, "participants", 5)
    assert row["survival_iqm"] == pytest.approx(30.0) and row["survival_mean"] == pytest.approx(220.0)
    assert np.isnan(row["survival_low"]) and np.isnan(row["survival_high"])
    third = pd.concat([rows, rows.iloc[:1].assign(participant="p03", steps=500)], ignore_index=True)
    est = interval([[10.0, 20.0, 30.0], [1000.0, 40.0], [500.0]])
    assert tuple(summarize(third).iloc[0][["survival_low", "survival_high"]]) == (est.low, est.high)
    assert "(n=2 participants, 5 ep.) |" in markdown_table(summarize(rows))
