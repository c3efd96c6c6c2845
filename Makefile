# rwpend — two commands on a fresh Debian 12 machine: `make demo` and `make test`.
.PHONY: setup setup-browser setup-cluster demo test test-fast test-unit test-loop test-system test-network test-browser bench soak lab firmware clean distclean

PY := .venv/bin/python

setup:
	@bash tools/setup.sh

setup-browser:   # setup + chromium and its driver (the console's page tests)
	@bash tools/setup.sh --browser

# setup + the Dask extra of ./rwpend sweep --scheduler (requirements-cluster.txt)
setup-cluster:
	@bash tools/setup.sh --cluster

demo: setup
	@./rwpend demo

# the unit and loop tiers on 2 workers (pytest-xdist: each test alone in its worker's process, own
# domain ids and tmp dirs); the system tests marked ``parallel`` (lockstep and services: no sample
# rate to keep) two files at once (on the slowest host 6 of those files took 217 s, 311 s one at a
# time); then the rest one at a time: real-time, network and browser tests keep their margins for
# one test on a loaded 2-core host (the whole system tier two at a time missed a real-time margin
# in 1 run of 3, and the identification through the emulated rig recorded incomplete runs); fails
# if any fails
test: setup-browser setup-cluster
	@./rwpend exec python -m pytest -m "unit or loop" -n 2; fast=$$?; \
	./rwpend exec python -m pytest -m "system and parallel" -n 2 --dist loadfile; two=$$?; \
	./rwpend exec python -m pytest -m "not (unit or loop or parallel)"; slow=$$?; \
	echo "make test: unit + loop exit $$fast, system two at once exit $$two, system + network + browser one at a time exit $$slow"; \
	[ $$fast -eq 0 ] && [ $$two -eq 0 ] && [ $$slow -eq 0 ]

# the tiers (pytest markers, given by the root conftest.py): unit, loop, system, network, browser
# the quick check: pure code and the loop in one process, no process of the stack started
test-fast: setup
	@./rwpend exec python -m pytest -m "unit or loop" -n 2

test-unit: setup
	@./rwpend exec python -m pytest -m unit

test-loop: setup
	@./rwpend exec python -m pytest -m loop

test-system: setup
	@./rwpend exec python -m pytest -m system

# the lab network tests alone (test hosts in network namespaces: root; part of make test too)
test-network: setup
	@./rwpend exec python -m pytest -m network

# the console's page tests in chromium (part of make test too)
test-browser: setup-browser
	@./rwpend exec python -m pytest -m browser

bench: setup
	@./rwpend bench

soak: setup
	@command -v nft >/dev/null 2>&1 || [ "$$(id -u)" != 0 ] || (apt-get update -qq && apt-get install -y -qq nftables) >/dev/null 2>&1 || true
	@./rwpend soak

# the book's 20 experiments on the simulator (lockstep) -> lab_out/<date>_<time>/ (+ report/index.html);
# an earlier run's directory is kept
lab: setup
	@./rwpend lab run all

# the rig's reference firmware (firmware/README.md): the STM32F405/F407 image with its size report,
# and the core built for this PC (the emulator's); installs Debian's gcc-arm-none-eabi where missing
firmware:
	@bash tools/setup.sh --firmware
	@$(MAKE) --no-print-directory -C firmware

clean:
	rm -rf build firmware/build demo_out bench_out soak_out lab_out lab_report .pytest_cache

distclean: clean
	rm -rf .venv
