# tvsd — `make run` (the main job, on the simulated plant) and `make test` (the whole suite).
# Both set themselves up on a fresh machine: a .venv, the Python packages, and (for the
# firmware) the distribution's AVR toolchain and simavr.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test lint pytest firmware-test firmware host-lib system-deps bench man clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $@

# The main job: tvsd on the simulated plant, in the foreground: spins the scanning aperture to
# 25 rev/s, scans the simulated scene and prints a status line per second until Ctrl-C.
# Drive it from another terminal: TVSD_SOCKET=.run/tvsd.sock .venv/bin/tvsctl status
run: $(STAMP) host-lib
	mkdir -p .run
	$(BIN)/tvsd --sil --realtime --demo --status-lines --socket .run/tvsd.sock --data-dir .run/data

system-deps:
	scripts/install-system-deps.sh

test: $(STAMP) system-deps lint pytest firmware-test

lint: $(STAMP)
	$(BIN)/ruff check tvsd tests
	$(BIN)/mypy
	$(BIN)/lint-imports

pytest: $(STAMP) host-lib
	$(BIN)/python -m pytest -q --durations=15

# The firmware core built for the host (the virtual MCU behind --sil): built here, before tvsd
# runs, never by tvsd itself. An installed wheel carries its own (setup.py).
host-lib: $(STAMP)
	$(MAKE) -C firmware host-lib

firmware-test: system-deps $(STAMP)
	@if [ -f firmware/Makefile ]; then $(MAKE) -C firmware all test; fi

# Release images of every MCU board (.elf/.hex/.bin in firmware/build/, size against each chip);
# flashing: hil/README.md.
firmware: system-deps $(STAMP)
	$(MAKE) -C firmware firmware

bench: $(STAMP)
	$(BIN)/tvsctl bench

# Man pages generated from the parsers: man/tvsctl.1, man/tvsd.1 (`man -l man/tvsctl.1`).
man: $(STAMP)
	$(BIN)/python -m tvsd.cli.manpage man

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache .run man
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
