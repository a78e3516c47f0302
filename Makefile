# Two commands do everything on a fresh machine:
#   make demo   - set up .venv and run the end-to-end demo on a simulated sensor
#   make test   - set up .venv and run the test suite
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
NOBLE := .venv-noble
NOBLE_STAMP := $(NOBLE)/.installed
# The Noble venv runs the floors without ROS (test/core, dataio, modelgap, sim, session,
# cli) and the house plan; not the nodes (no ROS wheels there), the firmware or the ament
# linters.
NOBLE_TESTS := $(wildcard test/core test/dataio test/modelgap test/session test/sim test/cli) \
	test/house/test_layout.py
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup demo demo-board test lint bench clean firmware tmux

setup: $(STAMP)
	@echo 'accel-calib is in $(BIN): ". $(BIN)/activate" puts it on your PATH'

# Each step says what it does and pip shows what it fetches (about a minute the first
# time; later runs skip this while the stamp file is newer than the requirements).
$(STAMP): setup.py requirements.txt requirements-ros.txt requirements-dev.txt
	@echo '==> [1/4] creating the virtual environment $(VENV)'
	$(PY) -m venv $(VENV)
	@echo '==> [2/4] upgrading pip'
	$(BIN)/pip install --upgrade pip
	@echo '==> [3/4] installing the dependencies (runtime, ROS 2 wheels, test tools)'
	$(BIN)/pip install -r requirements.txt -r requirements-ros.txt -r requirements-dev.txt
	@echo '==> [4/4] installing accel_calib_ros itself (editable)'
	$(BIN)/pip install --no-deps -e .
	touch $(STAMP)
	@echo '==> ready: run ". $(VENV)/bin/activate" to get accel-calib on your PATH'

# A second venv with Ubuntu Noble's versions of numpy, scipy, ... (constraints-noble.txt):
# the declared floors stay tested. No ROS wheels: it runs the core and CLI tests only,
# every warning an error (but pyparsing's own diagnostics, which -W error switches on
# inside matplotlib).
$(NOBLE_STAMP): setup.py requirements.txt requirements-dev.txt constraints-noble.txt
	@echo '==> [1/2] creating $(NOBLE) with Ubuntu Noble versions (constraints-noble.txt)'
	$(PY) -m venv $(NOBLE)
	grep -v '^ros-' requirements-dev.txt > $(NOBLE)/requirements-dev-noros.txt
	$(NOBLE)/bin/pip install -c constraints-noble.txt -r requirements.txt \
		-r $(NOBLE)/requirements-dev-noros.txt
	@echo '==> [2/2] installing accel_calib_ros into $(NOBLE) (editable)'
	$(NOBLE)/bin/pip install --no-deps -e .
	touch $(NOBLE_STAMP)

demo: $(STAMP)
	$(BIN)/python -m accel_calib_ros.sim.demo

# Firmware for the Arduino Uno (apt packages installed when missing; see docs/firmware.md).
firmware:
	@sh firmware/tools/ensure-toolchain.sh fw
	$(MAKE) -C firmware

# The demo on the emulated board: firmware ELF on simavr + emulated MPU-9250 -> driver.
demo-board: $(STAMP) firmware
	@sh firmware/tools/ensure-toolchain.sh hil
	$(BIN)/python -m accel_calib_ros.sim.demo --board

# The terminal test of "accel-calib guide" drives it in tmux (apt; it skips without).
tmux:
	@command -v tmux >/dev/null 2>&1 || { echo 'installing tmux (apt) for the guide test'; \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -q tmux >/dev/null 2>&1 || \
		{ apt-get update -q >/dev/null 2>&1 && \
		  DEBIAN_FRONTEND=noninteractive apt-get install -y -q tmux >/dev/null 2>&1; } || \
		echo 'tmux could not be installed: the guide terminal test will skip'; }

test: $(STAMP) $(NOBLE_STAMP) tmux
	$(BIN)/python -m pytest -q test
	@echo '==> core and CLI tests on Ubuntu Noble versions, warnings as errors ($(NOBLE))'
	$(NOBLE)/bin/python -W error -W 'ignore:::pyparsing' -m pytest -q -p no:cacheprovider \
		-m 'not ros' $(NOBLE_TESTS)

lint: $(STAMP)
	$(BIN)/flake8 accel_calib_ros test bench launch

bench: $(STAMP)
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) $(NOBLE) build *.egg-info
