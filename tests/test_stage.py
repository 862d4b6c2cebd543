"""The stage's clock (evaaa_baselines.stage), from plain numbers and a clock the test sets: the progress bar's rates are
smoothed and its ETA adds acting and gradient steps; the budget as asked and as trained; the time budgets count the
stage's earlier sessions; the time estimate is said once, from the session's own speed, with where a CPU budget ends
the stage; durations, rates and what a Ctrl-C waits for, in words.  Every expected text is worked out by hand."""

from __future__ import annotations

import math

import pytest

from evaaa_baselines.config import COMPUTE_BOUND_STEPS
from evaaa_baselines.stage import (
    Progress,
    StageClock,
    about,
    budget_text,
    duration,
    rate_text,
    stop_wait,
    trained_steps,
)


class Clock:
    """A wall clock the test moves, and a CPU clock running at ``cpu_share`` of its rate."""

    def __init__(self, cpu_share: float = 1.0):
        self.now, self.cpu_share = 0.0, cpu_share

    def wall(self) -> float:
        return self.now

    def cpu(self) -> float:
        return self.now * self.cpu_share


def make_clock(clock: Clock, budget: int, iteration: int = 100, **kwargs) -> StageClock:
    return StageClock(budget, iteration, wall=clock.wall, cpu=clock.cpu, **kwargs)


# ------------------------------------------------------------------------------------------------ progress
def test_progress_rate_is_smoothed_over_ppo_like_bursts():
    # 1,024 env steps collected in 1.6 s (one report per 8), then 0.4 s of 12 gradient steps: 512 env steps/s
    meter = Progress(window=60, steps=0, now=0.0)
    now, steps, rates = 0.0, 0, []
    for _ in range(60):  # two minutes
        for _ in range(128):
            now, steps = now + 1.6 / 128, steps + 8
            meter.add(steps, now=now)
            rates.append(meter.env_rate)
        now += 0.4
        meter.add(steps, updates=12, update_seconds=0.4, now=now)
        rates.append(meter.env_rate)
    late = rates[len(rates) // 2 :]
    assert 0.97 * 512 < min(late) and max(late) < 1.03 * 512  # steady within 3 %, where tqdm's swung 30-fold
    assert meter.session_rate == pytest.approx(512)
    assert meter.seconds_per_update == pytest.approx(0.4 / 12)
    assert meter.seconds_per_step == pytest.approx(1.6 / 1024)
    # 10,240 env steps and 120 gradient steps left: 16 s of acting and 4 s of updates
    assert meter.eta(10_240, 120) == pytest.approx(20.0)
    assert meter.eta(10_240, None) == pytest.approx(20.0, rel=0.03)  # from the smoothed whole-loop rate


def test_progress_eta_counts_the_gradient_steps_owed():
    # DreamerV3 S on a CPU: 8 env steps in 0.1 s, then 8 gradient steps of 10 s each
    meter = Progress(window=60, steps=1024, now=0.0)
    now, steps = 0.0, 1024
    for _ in range(5):
        now, steps = now + 0.1, steps + 8
        meter.add(steps, now=now)
        for _ in range(8):
            now += 10.0
            meter.add(steps, updates=1, update_seconds=10.0, now=now)
    assert meter.seconds_per_update == pytest.approx(10.0)
    assert meter.seconds_per_step == pytest.approx(0.1 / 8)
    left = 2_000_000 - steps
    assert meter.eta(left, left) == pytest.approx(left * (10.0 + 0.1 / 8))
    assert duration(meter.eta(left, left)) == "231.6 d"  # (2,000,000 - 1,064) x 10.0125 s


# ------------------------------------------------------------------------------------------------ words
def test_durations_and_rates_in_words():
    assert [duration(s) for s in (math.nan, -5, 59, 61, 3600, 3 * 3600 + 125, 2 * 86400)] == [
        "?",
        "0:00",
        "0:59",
        "1:01",
        "1:00 h",
        "3:02 h",
        "2.0 d",
    ]
    assert [about(s) for s in (math.inf, 89, 600, 7200, 3 * 86400)] == [
        "an unknown time",
        "about 89 seconds",
        "about 10 minutes",
        "about 2.0 hours",
        "about 3.0 days",
    ]
    assert [rate_text(x) for x in (0.1234, 99.94, 1234.4)] == ["0.123", "99.9", "1234"]


def test_the_budget_as_asked_and_as_trained():
    assert trained_steps(100, 32) == 128 and trained_steps(128, 32) == 128 and trained_steps(1, 1) == 1
    how = "2 worlds x 16 steps, then an update"
    assert budget_text(128, 32, how, None, COMPUTE_BOUND_STEPS) == "128 env steps"
    assert budget_text(100, 32, how, None, COMPUTE_BOUND_STEPS) == (
        "100 env steps asked: 128 trained, as the stage ends with the iteration that reaches its budget and one "
        "iteration is 32 env steps (2 worlds x 16 steps, then an update)"
    )
    # a CPU budget says the stage's size only where the step budget is out of reach
    assert budget_text(100, 32, how, 2.5, COMPUTE_BOUND_STEPS).startswith("100 env steps asked: 128 trained")
    assert budget_text(COMPUTE_BOUND_STEPS, 32, how, 2.5, COMPUTE_BOUND_STEPS) == (
        f"2.5 CPU-minutes (max_cpu_minutes; the budget of {COMPUTE_BOUND_STEPS:,} env steps is out of reach)"
    )


def test_what_a_ctrl_c_waits_for():
    assert stop_wait(False, None, 100) == "the iteration under way"  # before the stage starts: no speed known
    assert stop_wait(True, None, 100) == "the gradient step under way"
    meter = Progress(window=60, steps=0, now=0.0)
    meter.add(100, now=10.0)  # 10 env steps/s: an iteration of 100 takes 10 s
    meter.add(100, updates=2, update_seconds=60.0, now=70.0)  # 30 s a gradient step
    assert stop_wait(False, meter, 100) == "the iteration under way (one takes about 70 seconds here)"
    assert stop_wait(True, meter, 100) == "the gradient step under way (about 30 seconds each here)"


# ------------------------------------------------------------------------------------------------ time budgets
def test_the_time_budgets_count_the_stage_s_earlier_sessions():
    clock = Clock(cpu_share=0.5)
    stage = make_clock(clock, 1000, 10, max_minutes=1, spent_before=(50.0, 0.0))
    clock.now = 5.0
    assert stage.seconds_spent() == (55.0, 2.5) and stage.session_seconds() == 5.0
    assert not stage.out_of_time(10)
    clock.now = 10.0
    assert stage.out_of_time(10)  # 50 + 10 s: the minute is spent
    assert not stage.out_of_time(0)  # but not before an iteration of this session
    clock = Clock(cpu_share=0.5)
    cpu = make_clock(clock, 1000, 10, max_cpu_minutes=1, spent_before=(0.0, 49.0))
    unlimited = make_clock(clock, 1000, 10)
    clock.now = 21.0  # 10.5 CPU seconds of this session: 59.5 of the stage's
    assert not cpu.out_of_time(10)
    clock.now = 22.0
    assert cpu.out_of_time(10) and not unlimited.out_of_time(10)


def test_the_bar_s_text_and_the_session_s_last_line():
    clock = Clock()
    stage = make_clock(clock, 1000, 100, window=1e12)  # a window this long keeps the sums undecayed: exact rates
    clock.now = 10.0
    stage.add(100)
    assert stage.status(100, 0, None) == "env 10/s (avg 10) | ETA 1:30"  # 900 env steps left at 10/s
    planned = make_clock(clock, 1000, 100, window=1e12, planned_updates=lambda steps: steps // 10)
    clock.now = 20.0
    planned.add(100)
    clock.now = 30.0
    planned.add(100, 5, 10.0)
    # 100 env steps in 20 s; 5 gradient steps of 2 s; 0.1 s an env step besides: 900 x 0.1 + (100 - 5) x 2 s left
    assert planned.status(100, 5, 0.05) == "env 5/s (avg 5) | grad 5 0.25/s 2 s/update ratio 0.05 | ETA 4:40"
    assert planned.summary(100, 5) == "100 env steps, 5 env steps/s this session, 5 gradient steps, 0:20"
    whole = make_clock(clock, 100, 32)
    clock.now += 8.0
    assert whole.summary(128, 8) == (
        "128 env steps (100 asked, in whole iterations of 32), 16 env steps/s this session, 8 gradient steps, 0:08"
    )


# ------------------------------------------------------------------------------------------------ the estimate
def test_the_time_estimate_comes_from_the_run_s_own_speed():
    clock = Clock()
    stage = make_clock(clock, 1000)
    said = []
    for t, steps in ((10, 100), (20, 200), (30, 300)):  # 10 env steps/s
        clock.now = float(t)
        stage.add(steps)
        said.append(stage.estimate(steps, 0, done=False))
    assert said == [
        None,  # not before 20 s
        "about 80 seconds more for the 1,000 env steps (200 done), from this run's speed over its first 20 s here "
        "(10 env steps/s)",
        None,  # once
    ]
    late = make_clock(clock, 1000)
    clock.now += 30.0
    late.add(1000)
    assert late.estimate(1000, 0, done=True) is None  # nothing to estimate at the stage's end


def test_the_time_estimate_comes_with_the_first_timed_gradient_step():
    # PPO's shape: an iteration collects for 30 s, then makes its gradient steps (8 an iteration); the estimate is
    # said once the first of them is timed, not after the iteration's last
    clock = Clock()
    stage = make_clock(clock, 10_000, 1000, planned_updates=lambda steps: -(-steps // 1000) * 8)
    clock.now = 30.0
    stage.add(1000)
    assert stage.estimate(1000, 0, done=False) is None  # gradient steps owed, none timed yet
    clock.now = 31.0
    stage.add(1000, 1, 1.0)
    # 0.03 s an env step besides the gradient steps, 1 s each: 9,000 x 0.03 + 79 x 1 = 349 s; 1,000 env steps over
    # 30 x exp(-1/60) + 1 s of the decayed window: 32.2 env steps/s
    assert stage.estimate(1000, 1, done=False) == (
        "about 6 minutes more for the 10,000 env steps (1,000 done), from this run's speed over its first 31 s here "
        "(32.2 env steps/s, 1 s per gradient step)"
    )


def test_a_compute_bound_stage_says_when_its_cpu_budget_ends_it():
    # half a core: 10 env steps per wall second, 20 per CPU second; 60 CPU seconds in all, 10 spent at t=20 s
    for spent, wall_left, reach in ((0.0, "about 2 minutes", "1,200"), (30.0, "about 40 seconds", "600")):
        clock = Clock(cpu_share=0.5)
        stage = make_clock(clock, COMPUTE_BOUND_STEPS, max_cpu_minutes=1, spent_before=(0.0, spent))
        for t, steps in ((10, 100), (20, 200)):
            clock.now = float(t)
            stage.add(steps)
            line = stage.estimate(steps, 0, done=False)
        # 50 (or 20, with 30 spent in an earlier session) CPU seconds left: twice as many wall seconds at half a
        # core (100 s, or 40), at 10 env steps a wall second
        assert line.endswith(f"; max_cpu_minutes=1 ends it sooner: in {wall_left}, near {reach} env steps"), line
    clock = Clock()
    capped = make_clock(clock, 10_000, max_minutes=1)
    clock.now = 20.0
    capped.add(200)
    assert capped.estimate(200, 0, done=False).endswith("(10 env steps/s); max_minutes=1 ends it sooner")


def test_a_compute_bound_stage_with_a_prefill_says_how_far_its_gradient_steps_let_it_reach():
    # DreamerV3's shape: 1,000 env steps of prefill without gradient steps (0.01 s each), then one gradient step of
    # 1 s owed per 10 env steps: 0.11 s an env step from there on. Half a core; 60 CPU seconds in all
    clock = Clock(cpu_share=0.5)
    stage = make_clock(
        clock,
        COMPUTE_BOUND_STEPS,
        1,
        planned_updates=lambda steps: max(steps // 10 - 100, 0),
        window=1e12,  # a window this long keeps the sums undecayed: exact rates
        max_cpu_minutes=1,
    )
    for t, steps, updates in ((10, 1000, 0), (21, 1100, 10)):
        clock.now = float(t)
        stage.add(steps, updates - int(stage.meter.sums["updates"]), float(updates))
        line = stage.estimate(steps, updates, done=False)
    # 49.5 CPU seconds left at t=21 s: 99 s of wall time, 900 env steps at 0.11 s each (the session's 105 env
    # steps per CPU second, prefill included, would say 6,286)
    assert line.endswith("ends it sooner: in about 2 minutes, near 2,000 env steps"), line  # 99 s
