# rwpend — two commands on a fresh Debian 12 machine: `make demo` and `make test`.
.PHONY: setup demo test test-unit test-system bench clean distclean

PY := .venv/bin/python

setup:
	@bash tools/setup.sh

demo: setup
	@./rwpend demo

test: setup
	@./rwpend exec python -m pytest

test-unit: setup
	@./rwpend exec python -m pytest -m "not system"

test-system: setup
	@./rwpend exec python -m pytest -m system

bench: setup
	@./rwpend bench

clean:
	rm -rf build demo_out bench_out .pytest_cache

distclean: clean
	rm -rf .venv
