# Two entry points: `make demo` (set up, run the main job) and `make test` (set up, run the tests).
.PHONY: setup demo test test-fast lint bench-baseline clean

setup:
	@bash tools/setup.sh

demo: setup
	.venv/bin/leovr demo --out runs/demo

# one test process per core (pytest-xdist)
test: setup
	.venv/bin/python -m pytest -q -n auto

# the unit tests alone (tests marked `slow`, which run the pipeline end to end, left out)
test-fast: setup
	.venv/bin/python -m pytest -q -n auto -m "not slow"

lint: setup
	.venv/bin/ruff check .
	.venv/bin/ruff format --check .

bench-baseline: setup
	.venv/bin/leovr bench baseline --out runs/bench_baseline.json

clean:
	rm -rf runs .pytest_cache
