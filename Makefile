# Two commands do everything on a fresh machine:
#   make demo   - set up .venv and run the end-to-end demo on a simulated sensor
#   make test   - set up .venv and run the test suite
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup demo demo-board test lint bench clean firmware

setup: $(STAMP)

$(STAMP): setup.py requirements.txt requirements-ros.txt requirements-dev.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -r requirements.txt -r requirements-ros.txt -r requirements-dev.txt
	$(BIN)/pip install -q -e .
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m accel_calib_ros.demo

# Firmware for the Arduino Uno (apt packages installed when missing; see docs/firmware.md).
firmware:
	@sh firmware/tools/ensure-toolchain.sh fw
	$(MAKE) -C firmware

# The demo on the emulated board: firmware ELF on simavr + emulated MPU-9250 -> driver.
demo-board: $(STAMP) firmware
	@sh firmware/tools/ensure-toolchain.sh hil
	$(BIN)/python -m accel_calib_ros.demo --board

test: $(STAMP)
	$(BIN)/python -m pytest -q test

lint: $(STAMP)
	$(BIN)/flake8 accel_calib_ros test bench launch

bench: $(STAMP)
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) build *.egg-info
