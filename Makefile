# The two commands of the README, and a few more. Each target sets up what it needs first (scripts/setup.sh).
PY := .venv/bin/python

ARGS ?=

.PHONY: setup train demo test test-fast lint bench pictures

setup:
	@bash scripts/setup.sh

# Every script takes key=value arguments (python scripts/<name>.py --help lists them); ARGS passes them on.
# the main job: train a baseline (Hydra overrides in ARGS, e.g. make train ARGS="algo=ppo level=1-1 total_steps=10000";
# ARGS="algo=dreamer level=3-2" is DreamerV3 size S, for a GPU: algo=dreamer_xs is its CPU size)
train: setup
	$(PY) scripts/train.py $(ARGS)

# a quick look: a short random-policy rollout that writes a video and prints steps/s
demo: setup
	$(PY) scripts/demo.py $(ARGS)

# the suite on every core (pytest-xdist: one worker per core, each test file on one worker, so a file's shared
# fixtures are built once); add -n 0 to a pytest call to run it in one process. The 30 slowest tests of over 20 s are
# listed at the end, so that CI's log shows where its time goes
XDIST := -n auto --dist loadfile --no-loadscope-reorder
DURATIONS := --durations=30 --durations-min=20

test: setup
	$(PY) -m pytest -q $(XDIST) $(DURATIONS)

test-fast: setup
	$(PY) -m pytest -q -m "not slow" $(XDIST)

# ruff: lint and format check (CI runs it); `.venv/bin/ruff format .` and `ruff check --fix .` mend
lint: setup
	.venv/bin/ruff check .
	.venv/bin/ruff format --check .

bench: setup
	$(PY) scripts/bench_env.py $(ARGS)

pictures: setup
	$(PY) scripts/render_levels.py $(ARGS)
