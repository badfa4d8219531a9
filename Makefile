# Two commands for a new user: `make demo` and `make test`. Both are idempotent.
# `make bench` reruns the benchmarks; each rewrites its page in docs/results/.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: setup demo test format bench clean golden

setup: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -c constraints.txt -e ".[dev,ray]"
	touch $(STAMP)

demo: setup
	$(VENV)/bin/rigjax demo --out build/demo
	$(VENV)/bin/learnstitch demo --out build/demo/stitch
	$(VENV)/bin/learnstitch demo --fullres 1024 --out build/demo/fullres
	$(VENV)/bin/learnstitch demo --dual 1440 --out build/demo/dual
	$(VENV)/bin/rigjax calibrate build/demo/dual/frame0.png build/demo/dual/frame1.png build/demo/dual/frame2.png \
		--template configs/rig/dual_fisheye.yaml -o build/demo/dual/rig.pto --render build/demo/dual/pano.jpg --width 2048
	$(VENV)/bin/learnstitch demo --video 960 --out build/demo/video
	$(VENV)/bin/rigjax calibrate --video build/demo/video/clip.mp4 --every 15 --frames 3 \
		--template configs/rig/dual_fisheye.yaml -o build/demo/video/rig.pto
	$(VENV)/bin/learnstitch stitch --rig build/demo/video/rig.pto --video build/demo/video/clip.mp4 \
		-o build/demo/video/pano.mp4 --width 1920 --quiet

# Lint and format checks first (they rewrite nothing: `make format` does), then the suite on two
# workers, one test file each at a time (module fixtures stay in one process): much of the suite is
# single-threaded XLA compilation, so this is ~25% faster even on 2 cores. A worker that crashes
# ends the run (--max-worker-restart=0): xdist's file scheduler can wait forever on a replacement.
test: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q -n 2 --dist loadfile --max-worker-restart=0 tests

format: setup
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

bench: setup
	$(PY) -m pip install --quiet -c constraints.txt -e ".[dev,bench,ray]"
	$(PY) benchmarks/hugin_agreement.py
	$(PY) benchmarks/pto_fuzz.py
	$(PY) benchmarks/pto_parse_speed.py
	$(PY) benchmarks/cli_latency.py
	$(PY) benchmarks/transform_speed.py
	$(PY) benchmarks/solve_speed.py
	$(PY) benchmarks/bundle_adjustment.py
	$(PY) benchmarks/paper_schedules.py --out build/bench
	$(PY) benchmarks/hugin_compare.py
	$(PY) benchmarks/calibrate_montecarlo.py
	$(PY) benchmarks/prune_compare.py
	$(PY) benchmarks/dual_fisheye.py
	$(PY) benchmarks/lens_from_motion.py --clips 16
	$(PY) benchmarks/motion_depth_policies.py
	$(PY) benchmarks/synth_speed.py --samples 6
	$(PY) benchmarks/parallax_table.py
	$(PY) benchmarks/calibrated_baseline.py --samples 16 --configs paper_d02 paper_d04 cpu_tiny_d02 cpu_tiny_d04
	$(PY) benchmarks/seam_matches.py --samples 16
	$(PY) benchmarks/track_errors.py --samples 16
	$(PY) benchmarks/stitch_speed.py
	$(PY) benchmarks/stitch_fullres.py --samples 3
	$(PY) benchmarks/stitch_fullres_speed.py
	$(PY) benchmarks/stitch_anyrig.py
	$(PY) benchmarks/stitch_losses.py
	$(PY) benchmarks/stitch_video.py
	$(PY) benchmarks/stitch_video_flicker.py --network
	$(PY) benchmarks/stitch_batch.py
	$(PY) benchmarks/stitch_geometry.py
	$(PY) benchmarks/stitch_targets.py
	$(PY) benchmarks/stitch_depth_errors.py --samples 32
	$(PY) benchmarks/stitch_pole.py
	$(PY) benchmarks/stitch_near.py

# Re-record the golden data from Hugin's pano_trafo, autooptimiser and nona (needs `apt-get install hugin-tools`).
golden: setup
	$(PYTHON) tests/rigjax/data/make_golden.py
	$(PY) tests/rigjax/data/make_golden_optimiser.py
	$(PY) tests/rigjax/data/make_golden_photometry.py

clean:
	rm -rf $(VENV) build .pytest_cache
