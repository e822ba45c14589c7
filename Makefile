# The two commands of the README (both install what is needed first, idempotently):
#   make demo    set up, then run the demo (exits by itself; `make demo KEEP=1` keeps it running for rviz)
#   make test    set up, then run the whole test suite (what .ci/run calls)
# Also: make setup, make bench, make clean.
SHELL := /bin/bash
.DEFAULT_GOAL := help

DEMO_ARGS ?=
ifdef KEEP
DEMO_ARGS += --keep-running
endif
ifdef RVIZ
DEMO_ARGS += --keep-running --rviz
endif

.PHONY: help setup demo test bench clean

help:
	@sed -n '1,6p' Makefile

setup:
	@bash scripts/setup.sh

demo: setup
	@scripts/in_env.sh python -m robot_demo $(DEMO_ARGS)

test: setup
	@scripts/in_env.sh bash scripts/run_tests.sh $(TEST_ARGS)

bench: setup
	@scripts/in_env.sh pip install -q -c constraints.txt -r bench/requirements-bench.txt
	@scripts/in_env.sh bash bench/run_all.sh

clean:
	rm -rf build devel install .setup artifacts src/CMakeLists.txt
