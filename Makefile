# okid_ros: `make demo` runs the main job, `make test` the tests; both set up first when needed.
# `make setup` builds the pip route in .venv (see scripts/setup_venv.sh); `make clean` removes it.

SHELL := /bin/bash
VENV := .venv
# Interpreter for the venv (CPython 3.11); empty: the setup script picks Debian's python3.11.
PYTHON ?=
# One process: with one pytest worker per core (`make test PYTEST_ARGS="-q -n auto --dist
# loadscope"`, 7.5 instead of 15 min here) the DDS tests' fixed-rate streams lose more to the
# load, and two of them failed in six such runs.
PYTEST_ARGS ?= -q

SETUP_STAMP := $(VENV)/.okid-stamps/setup
# Setup reruns when one of these changes; its stages skip what is already up to date.
SETUP_INPUTS := scripts/setup_venv.sh $(wildcard requirements/*.txt) \
	package.xml setup.py setup.cfg \
	msg_defs/package.xml msg_defs/CMakeLists.txt $(wildcard msg_defs/msg/*.msg)

.PHONY: setup test demo clean

setup: $(SETUP_STAMP)

$(SETUP_STAMP): $(SETUP_INPUTS)
	VENV="$(VENV)" PYTHON="$(PYTHON)" bash scripts/setup_venv.sh
	touch "$@"

test: setup
	$(VENV)/bin/python -m pytest $(PYTEST_ARGS)

demo: setup
	$(VENV)/bin/okid-ros demo --out-dir out/demo

clean:
	rm -rf "$(VENV)" build install log okid_ros.egg-info
