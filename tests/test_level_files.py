"""Level loading, inheritance, overrides and validation errors (evaaa.level_files, evaaa.level)."""

from __future__ import annotations

import re
from importlib import resources

import pytest
import yaml

import evaaa
from evaaa.level import Level, LevelError
from evaaa.level_files import level_names, load_level


# ------------------------------------------------------------------------------------------------ loading
@pytest.mark.parametrize("name", evaaa.LEVELS)
def test_every_level_loads(name):
    level = load_level(name)
    assert isinstance(level, Level)
    assert level.name == name
    assert level.kind == "training"
    assert level.description


def test_level_names_cover_levels_and_testbeds():
    assert level_names() == evaaa.LEVELS + evaaa.TESTBEDS
    assert "1-1" in evaaa.LEVELS and "1-2" in evaaa.LEVELS


def test_defaults_reach_every_level():
    level = load_level("1-1")
    assert level.physiology.decay.satiation == pytest.approx(-0.0135)
    assert level.physiology.decay.hydration == pytest.approx(-0.009)
    assert level.physiology.decay.damage == pytest.approx(-0.01)
    assert level.physiology.bounds.damage == (0.0, 100.0)
    assert level.reward.name == "squared"
    assert level.thermal.hotspots.count == 20


def test_1_2_inherits_from_1_1_with_corner_cubes():
    a, b = load_level("1-1"), load_level("1-2")
    assert a.resources["food"].count == 50 and a.resources["water"].count == 50
    food, water = b.resources["food"], b.resources["water"]
    assert (food.count, water.count) == (10, 10)
    # opposite corners: food south-west, water north-east
    assert food.x == (-40.0, -20.0) and food.y == (-40.0, -20.0)
    assert water.x == (20.0, 40.0) and water.y == (20.0, 40.0)
    # what 1-2 does not state comes from 1-1 (merged key by key inside each group)
    assert food.kind == "food" and water.kind == "water"
    assert food.size == a.resources["food"].size and food.respawn == a.resources["food"].respawn
    assert b.thermal == a.thermal
    assert b.agent == a.agent
    assert b.physiology == a.physiology
    assert b.description != a.description


# ------------------------------------------------------------------------------------------------ overrides
@pytest.mark.parametrize(
    "overrides",
    [{"agent.move_speed": 10}, {"agent": {"move_speed": 10}}],
    ids=["dotted", "nested"],
)
def test_overrides_apply(overrides):
    level = load_level("1-1", overrides)
    assert level.agent.move_speed == 10.0
    assert isinstance(level.agent.move_speed, float)
    assert level.agent.turn_degrees == load_level("1-1").agent.turn_degrees  # siblings untouched


def test_overrides_do_not_leak_into_later_loads():
    load_level("1-1", {"agent.move_speed": 10, "resources.food.count": 3})
    fresh = load_level("1-1")
    assert fresh.agent.move_speed == 20.0
    assert fresh.resources["food"].count == 50


def test_deep_overrides():
    level = load_level(
        "1-2",
        {"physiology.decay": {"satiation": -0.02}, "episode.max_steps": 100, "resources.water.count": 4},
    )
    assert level.physiology.decay.satiation == -0.02
    assert level.physiology.decay.hydration == pytest.approx(-0.009)  # rest of the section kept
    assert level.episode.max_steps == 100 and isinstance(level.episode.max_steps, int)
    assert level.resources["water"].count == 4
    assert level.resources["water"].x == (20.0, 40.0)


def test_reward_name_override():
    assert load_level("1-1", {"reward.name": "neg_distance"}).reward.name == "neg_distance"


# ------------------------------------------------------------------------------------------------ errors
def test_level_error_is_a_value_error():
    assert issubclass(LevelError, ValueError)
    with pytest.raises(ValueError):
        load_level("no-such-level")


def test_unknown_level_lists_the_available_ones():
    with pytest.raises(LevelError, match=r"unknown level 'no-such-level'.*available: 1-1, 1-2"):
        load_level("no-such-level")


@pytest.mark.parametrize(
    "overrides, pattern",
    [
        # unknown field in a section: the section's allowed keys
        ({"agent.move_sped": 10}, r"agent\.move_sped: unknown field; allowed: .*\bmove_speed\b.*\bturn_degrees\b"),
        ({"agent": {"move_sped": 10}}, r"agent\.move_sped: unknown field; allowed: .*\bmove_speed\b"),
        ({"resources.food.colour": "red"}, r"resources\.food\.colour: unknown field; allowed: kind, count, respawn"),
        ({"foo": 1}, r"foo: unknown field; allowed: .*\bagent\b.*\bphysiology\b"),
        # unknown section on the way down a dotted path
        ({"agnt.move_speed": 10}, r"'agnt' is not a field; allowed here: .*\bagent\b"),
        ({"resources.fruit.count": 5}, r"'resources\.fruit' is not a field; allowed here: food, water"),
        # descending into a value
        ({"agent.move_speed.x": 1}, r"'agent\.move_speed' is a value"),
    ],
)
def test_unknown_keys_name_the_field_and_the_allowed_keys(overrides, pattern):
    with pytest.raises(LevelError, match=pattern):
        load_level("1-1", overrides)


@pytest.mark.parametrize(
    "overrides, pattern",
    [
        ({"agent.move_speed": "fast"}, r"agent\.move_speed: .*valid number.*'fast'"),
        ({"episode.max_steps": 1.5}, r"episode\.max_steps: .*integer"),
        ({"agent.auto_eat": "maybe"}, r"agent\.auto_eat: .*valid boolean"),
        ({"arena.floor": "lava"}, r"arena\.floor: .*'ground' or 'gray'"),
    ],
)
def test_wrong_type(overrides, pattern):
    with pytest.raises(LevelError, match=pattern):
        load_level("1-1", overrides)


@pytest.mark.parametrize(
    "overrides, pattern",
    [
        ({"agent.move_speed": -1}, r"agent\.move_speed: .*greater than 0"),
        ({"agent.turn_degrees": 180}, r"agent\.turn_degrees: .*less than 180"),
        ({"sensors.collision.rays": 15}, r"sensors\.collision: rays \(15\) must be a multiple of sectors \(10\)"),
        (
            {"physiology.start.satiation": 20},
            r"start\.satiation = 20\.0 lies outside bounds\.satiation = \[-15\.0, 15\.0\]",
        ),
        ({"physiology.start.damage": -1}, r"start\.damage = -1\.0 lies outside bounds\.damage"),
        ({"agent.spawn_x": [10, -10]}, r"agent\.spawn_x: expected \[low, high\] with low <= high"),
        ({"physiology.bounds.temperature": [5, -5]}, r"physiology\.bounds\.temperature: .*low <= high"),
        ({"resources.food.x": [-60, 0]}, r"resources\.food\.x = \[-60\.0, 0\.0\] leaves the floor \[-50\.0, 50\.0\]"),
        ({"arena.size": [40, 40]}, r"resources\.\w+\.[xy] = .* leaves the floor \[-20\.0, 20\.0\]"),
        ({"resources.water.count": -1}, r"resources\.water\.count: .*greater than or equal to 0"),
    ],
)
def test_out_of_range(overrides, pattern):
    with pytest.raises(LevelError, match=pattern):
        load_level("1-1", overrides)


def test_error_names_the_level():
    with pytest.raises(LevelError, match=r"invalid level '1-2'"):
        load_level("1-2", {"agent.move_speed": -1})


def test_several_errors_are_all_reported():
    with pytest.raises(LevelError) as info:
        load_level("1-1", {"agent.move_speed": -1, "agent.mass": 0})
    assert "agent.move_speed" in str(info.value) and "agent.mass" in str(info.value)


@pytest.mark.parametrize("field", ["name", "kind"])
def test_identity_cannot_be_overridden(field):
    with pytest.raises(LevelError, match=rf"override '{field}' cannot change a level's identity"):
        load_level("1-1", {field: "1-2"})


def test_reward_name_error_lists_the_four_names():
    with pytest.raises(LevelError, match=r"reward\.name") as info:
        load_level("1-1", {"reward.name": "dense"})
    message = str(info.value)
    for name in evaaa.REWARDS:
        assert re.search(rf"'{name}'", message), name
    assert "'dense'" in message


# ------------------------------------------------------------------------------------------------ broken but typed
@pytest.mark.parametrize(
    "overrides, pattern",
    [
        ({"physiology.food_value": float("nan")}, r"physiology\.food_value: Input should be a finite number"),
        ({"physiology.food_value": "nan"}, r"physiology\.food_value: Input should be a valid number"),
        ({"thermal.base_temperature": float("inf")}, r"thermal\.base_temperature: .*finite"),
        ({"agent.spawn_x": [float("-inf"), 0]}, r"agent\.spawn_x\.0: .*finite"),
        ({"resources.food.size": float("inf")}, r"resources\.food\.size.*finite"),
        ({"events.switch.set.satiation": float("nan")}, r"events\.switch\.set\.satiation: .*finite"),
    ],
)
def test_nan_and_infinity_are_refused_everywhere(overrides, pattern):
    base = "goal-manipulation-food-to-water" if any(k.startswith("events") for k in overrides) else "1-1"
    with pytest.raises(LevelError, match=pattern):
        load_level(base, overrides)


@pytest.mark.parametrize(
    "overrides, pattern",
    [
        ({"reward.weights.satiation": 1e308}, r"reward\.weights\.satiation: must lie within \[-1e\+06, 1e\+06\]"),
        ({"physiology.bounds.satiation": [-1e9, 1e9]}, r"physiology\.bounds\.satiation: must lie within"),
        ({"episode.max_steps": 10**12}, r"episode\.max_steps: must lie within"),
        ({"thermal.hotspots.count": 10**9}, r"thermal\.hotspots\.count: .*less than or equal to 1000"),
        ({"thermal.hotspots.size": 5000}, r"thermal\.hotspots\.size: .*less than or equal to 1000"),
        ({"thermal.sigma": 1e9}, r"thermal\.sigma: .*less than or equal to 100"),
        # each within its own bound, too much work together at every reset
        ({"thermal.grid": [1000, 1000], "thermal.sigma": 20}, r"thermal: sigma = 20 cells over a grid of 1000 x 1000"),
        ({"arena.size": [1e5, 100]}, r"arena\.size\.0: .*less than or equal to 1000"),
        ({"arena.size": [1, 100]}, r"arena\.size\.0: .*greater than or equal to 2"),
        ({"obstacles.bushes.scale": [[0, 1], [1, 1], [1, 1]]}, r"obstacles\.bushes\.scale: every scale must be > 0"),
    ],
)
def test_sizes_and_counts_are_bounded_by_what_the_machine_can_do(overrides, pattern):
    with pytest.raises(LevelError, match=pattern):
        load_level("2-1", overrides)


def test_the_default_smoothing_stays_allowed():
    assert load_level("1-1", {"thermal.grid": [1000, 1000], "thermal.sigma": 3}).thermal.sigma == 3


@pytest.mark.parametrize(
    "overrides, pattern",
    [
        (
            {"agent.start": "fixed", "agent.start_position": [60, 0]},
            r"agent\.start_position = \[60, 0\] is off the floor.*x in \[-49\.5, 49\.5\]",
        ),
        # a random start falls back to the fixed position when its box is full: that must be on the floor too
        ({"agent.start_position": [0, -50]}, r"agent\.start_position = \[0, -50\] is off the floor"),
        ({"agent.spawn_y": [60, 70]}, r"agent\.spawn_y = \[60, 70\] misses the floor"),
        (
            {"sensors.vision.near": 5, "sensors.vision.far": 1},
            r"sensors\.vision: near \(5\) must be less than far \(1\)",
        ),
        (
            {"daynight.enabled": True, "daynight.night_far": 0.2},
            r"daynight\.night_far \(0\.2\) must exceed sensors\.vision\.near \(0\.3\)",
        ),
    ],
)
def test_rules_across_fields_are_checked_at_load_time(overrides, pattern):
    with pytest.raises(LevelError, match=pattern):
        load_level("1-1", overrides)


def test_a_random_spawn_box_partly_off_the_floor_is_kept():
    level = load_level("1-1", {"agent.spawn_x": [-80, 0]})
    assert level.agent.spawn_x == (-80.0, 0.0)  # the part on the floor is used (worldgen clips it)


def test_bodies_in_all_are_bounded():
    assert load_level("2-2", {"obstacles.bushes.count": 1000}).obstacles["bushes"].count == 1000
    # each group within its own limit, too many together for MuJoCo's collision detection
    with pytest.raises(LevelError, match=r"obstacles' count and the solid resources' \(ponds\) count add up to 1514"):
        load_level("2-2", {"obstacles.bushes.count": 1000, "obstacles.rocks.count": 500})
    with pytest.raises(LevelError, match=r"resources' count adds up to 2004 items; at most 2000"):
        load_level("2-2", {"resources.apples_a.count": 1000, "resources.apples_b.count": 1000})


def test_hotspots_and_landmarks_are_bounded_in_all():
    with pytest.raises(LevelError, match=r"hotspots\.count = 1000 squares of hotspots\.size = 999 cells paint"):
        load_level(
            "1-1",
            {
                "thermal.grid": [1000, 1000],
                "thermal.sigma": 0,
                "thermal.hotspots.count": 1000,
                "thermal.hotspots.size": 999,
            },
        )
    with pytest.raises(LevelError, match=r"landmarks: pattern places 12100 landmark points; at most 10000"):
        load_level("4-1", {"landmarks.pattern": [[10] * 11] * 11})


# ------------------------------------------------------------------------------------------------ level lists and files
def test_level_lists_come_from_the_files_kind_and_order():
    for names, kind in ((evaaa.LEVELS, "training"), (evaaa.TESTBEDS, "testbed")):
        assert [evaaa.load_level(n).kind for n in names] == [kind] * len(names)
        orders = [
            yaml.safe_load(resources.files("evaaa.levels").joinpath(f"{n}.yaml").read_text())["order"] for n in names
        ]
        assert orders == list(range(1, len(names) + 1))
    listed = {
        p.name[:-5]
        for p in resources.files("evaaa.levels").iterdir()
        if p.name.endswith(".yaml") and not p.name.startswith("_")
    }
    assert listed == set(evaaa.LEVELS + evaaa.TESTBEDS)


def test_a_users_level_file_extends_a_packaged_level_and_registers_by_name(tmp_path):
    base = tmp_path / "bases" / "hot-field.yaml"
    base.parent.mkdir()
    base.write_text('extends: "1-1"\nthermal: {base_temperature: 10.0}\n')
    mine = tmp_path / "hot-and-bare.yaml"
    mine.write_text("extends: bases/hot-field.yaml\nresources: {water: null}\n")
    level = evaaa.load_level(mine, {"episode.max_steps": 7})
    assert level.name == "hot-and-bare" and level.kind == "training"
    assert level.thermal.base_temperature == 10.0 and list(level.resources) == ["food"]
    assert level.episode.max_steps == 7 and level.agent == evaaa.load_level("1-1").agent
    assert evaaa.register_level(mine) == "hot-and-bare"
    assert evaaa.load_level("hot-and-bare") == evaaa.load_level(mine)
    clash = tmp_path / "1-1.yaml"
    clash.write_text('extends: "1-2"\n')
    with pytest.raises(LevelError, match="already a packaged level"):
        evaaa.register_level(clash)


@pytest.mark.parametrize(
    "text, message",
    [
        ("extends: no-such-level\n", "extends: 'no-such-level' is not a packaged level"),
        ("[1, 2]\n", "must hold a mapping"),
        ("agent: {move_speed: [\n", "not valid YAML"),
        ("agent: {move_sped: 3}\n", "agent.move_sped: unknown field"),
    ],
)
def test_a_bad_users_level_file_is_refused_naming_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(LevelError, match=message):
        evaaa.load_level(path)
    with pytest.raises(LevelError, match="cannot be read"):
        evaaa.load_level(tmp_path / "absent.yaml")
