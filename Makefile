# Two commands on a fresh machine: `make demo` and `make test` (see README).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SYSTAMP := $(VENV)/.system-packages

.PHONY: demo test lint typecheck pytest bench chaos fuzz fuzz-companion clean system-packages pi-check

# Debian/Raspberry Pi OS packages the project needs: venv support for python3,
# systemd's systemd-analyze for the unit-file tests, and chromium + chromium-driver for
# the console's browser tests. Installed only when missing; re-checked when the list changes.
$(SYSTAMP): tools/system-packages.sh
	@bash tools/system-packages.sh
	@mkdir -p $(VENV) && touch $@

$(STAMP): pyproject.toml $(SYSTAMP)
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,dev]'
	# MAVProxy is a test peer (a real ground station/hub). Its own requirements pull in
	# opencv-python 5.x, matplotlib and vtk for map and GUI modules we do not use; the
	# 5.x cv2 would shadow our headless 4.x, so it goes in without them.
	$(BIN)/python -m pip install --quiet --no-deps 'mavproxy>=1.8.70' pynmeagps defusedxml
	# The person models (MediaPipe, Apache-2.0) from the npm registry, checked by sha256,
	# into .venv/share/rescue-companion/models; nothing is downloaded at run time.
	$(BIN)/rescue-companion models fetch
	# The console's map library (Leaflet, BSD-2-Clause) from the npm registry, checked by
	# sha512 and sha256, into .venv/share/rescue-companion/web; never fetched at run time.
	$(BIN)/rescue-hq assets fetch
	@touch $@

# A set-up from before a model was added to companion/vision/models.py fetches it here
# (the fetch checks every file by sha256 and downloads only what is missing).
MODELS := $(VENV)/.models
$(MODELS): companion/vision/models.py $(STAMP)
	$(BIN)/rescue-companion models fetch
	@touch $@

demo: $(STAMP) $(MODELS)
	$(BIN)/rescue-sim demo

test: $(STAMP) lint typecheck pytest

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy companion mavlink_io fusion scenarios hq npmfetch

# --durations: every run, CI's included, names the slowest tests (the run's goal is
# under 10 minutes on 2 cores).
pytest: $(STAMP) $(MODELS)
	$(BIN)/python -m pytest -q -n auto --durations=15

bench: $(STAMP) $(MODELS)
	$(BIN)/python -m bench

# A simulated mission under radio loss, kills, restarts, a reboot and a full disk
# (bench/chaos.py): 20 minutes and seed 16 unless CHAOS_SECONDS / CHAOS_SEED say
# otherwise; writes its section of BENCHMARKS.md and fails when a check fails.
CHAOS_SECONDS ?= 1200
CHAOS_SEED ?= 16
chaos: $(STAMP) $(MODELS)
	CHAOS_SECONDS=$(CHAOS_SECONDS) CHAOS_SEED=$(CHAOS_SEED) $(BIN)/python -m bench.chaos

# The vehicle-link fuzzer for 60 s with a fresh seed (the default test run gives it
# 3 s with seed 16); a failure prints the seed, FUZZ_SEED=<seed> repeats it.
fuzz-companion: $(STAMP) $(MODELS)
	FUZZ_SECONDS=$${FUZZ_SECONDS:-60} FUZZ_SEED=$${FUZZ_SEED:-$$(date +%s)} \
		$(BIN)/python -m pytest -q tests/test_mavlink_vehicle_fuzz.py

# The HQ receive path and the dialect decoder under 40000 hostile valid-CRC messages
# (the default test run sends 1500). A fresh seed each time; FUZZ_SEED=N replays one.
FUZZ_SEED ?= $(shell od -An -N4 -tu4 /dev/urandom | tr -d ' ')
fuzz: $(STAMP)
	@echo "fuzz seed $(FUZZ_SEED)"
	FUZZ_SEED=$(FUZZ_SEED) FUZZ_MESSAGES=40000 $(BIN)/python -m pytest -q tests/test_hq_fuzz.py

# The README's set-up and the detect/replay results on aarch64 (a cached Debian bookworm
# arm64 root under qemu-user), compared with this host's; fails when they differ
# (tools/pi-check.sh; needs root; not part of `make test`: about an hour the first time).
pi-check: $(STAMP) $(MODELS)
	bash tools/pi-check.sh

clean:
	rm -rf $(VENV) build *.egg-info .mypy_cache .ruff_cache .pytest_cache
