# okid_ros: `make demo` runs the main job, `make test` the tests; both set up first when needed.
# `make setup` builds the pip route in .venv (see scripts/setup_venv.sh); `make clean` removes it.

SHELL := /bin/bash
VENV := .venv
# Interpreter for the venv (CPython 3.11); empty: the setup script picks Debian's python3.11.
PYTHON ?=
# The tests in two runs: those without DDS with one pytest worker per core (pytest-xdist, a
# module's tests on one worker), then the tests marked `dds` in one process: their fixed-rate
# streams lose samples to a second worker's load (two failed in six all-parallel runs). The
# `dds_startup` tests (nodes that only start, refuse or exit) join the first run: each worker
# has a ROS domain of its own (test/conftest.py), and they check no rate.
# TEST_WORKERS=0 runs the first part in one process too. A run that selects no test of a part
# (exit status 5) passes that part.
PARALLEL_TESTS := not dds or dds_startup
SERIAL_TESTS := dds and not dds_startup
TEST_WORKERS ?= auto
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

# The test runs write bytecode though the environment may say not to (PYTHONDONTWRITEBYTECODE, set
# on the CI machines): without it every pytest session rewrote the asserts of all test modules again
# (most of its collection's CPU) and every node or CLI process compiled okid_ros again. The .pyc
# files go to __pycache__ folders, which git ignores. (Python reads an empty value as unset.)
test: export PYTHONDONTWRITEBYTECODE :=
test: setup
	status=0; \
	$(VENV)/bin/python -m pytest -m "$(PARALLEL_TESTS)" -n $(TEST_WORKERS) --dist loadscope $(PYTEST_ARGS) || [ $$? -eq 5 ] || status=1; \
	$(VENV)/bin/python -m pytest -m "$(SERIAL_TESTS)" $(PYTEST_ARGS) || [ $$? -eq 5 ] || status=1; \
	exit $$status

demo: setup
	$(VENV)/bin/okid-ros demo --out-dir out/demo

clean:
	rm -rf "$(VENV)" build install log okid_ros.egg-info
