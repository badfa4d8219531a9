# Two commands for a new user: `make demo` and `make test`. Both are idempotent.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: setup demo test bench clean golden

setup: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -c constraints.txt -e ".[dev]"
	touch $(STAMP)

demo: setup
	$(VENV)/bin/rigjax demo --out build/demo
	$(VENV)/bin/learnstitch demo --out build/demo/stitch

# Two workers, one test file each at a time (module fixtures stay in one process): much of the suite
# is single-threaded XLA compilation, so this is ~25% faster even on 2 cores.
test: setup
	$(PY) -m pytest -q -n 2 --dist loadfile tests

bench: setup
	$(PY) -m pip install --quiet -c constraints.txt -e ".[dev,bench]"
	$(PY) tests/benchmarks/transform_speed.py
	$(PY) tests/benchmarks/solve_speed.py
	$(PY) tests/benchmarks/paper_schedules.py --out build/bench
	$(PY) tests/benchmarks/hugin_compare.py
	$(PY) tests/benchmarks/calibrate_montecarlo.py
	$(PY) tests/benchmarks/prune_compare.py
	$(PY) tests/benchmarks/dual_fisheye.py
	$(PY) tests/benchmarks/synth_speed.py --samples 6
	$(PY) tests/benchmarks/parallax_table.py
	$(PY) tests/benchmarks/calibrated_baseline.py --samples 16 --configs paper_d02 paper_d04 cpu_tiny_d02 cpu_tiny_d04
	$(PY) tests/benchmarks/stitch_speed.py
	$(PY) tests/benchmarks/stitch_losses.py

# Re-record the golden data from Hugin's pano_trafo and autooptimiser (needs `apt-get install hugin-tools`).
golden: setup
	$(PYTHON) tests/data/make_golden.py
	$(PY) tests/data/make_golden_optimiser.py

clean:
	rm -rf $(VENV) build .pytest_cache
