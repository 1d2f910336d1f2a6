# The two commands of the README: `make demo` and `make test`.
# Both create .venv and install hilbench with its test extra on first use.
VENV ?= .venv
PYTHON ?= python3
PY := $(VENV)/bin/python

.PHONY: demo test lint bench install

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $@

install: $(VENV)/.installed

demo: $(VENV)/.installed
	$(VENV)/bin/hilbench demo

test: $(VENV)/.installed
	$(PY) -m ruff check hilbench tests tools
	$(PY) -m pytest -q

bench: $(VENV)/.installed
	$(PY) tools/bench_dynamixel.py
	$(PY) tools/bench_monitor.py
	$(PY) tools/bench_board.py
	$(PY) tools/bench_profiler.py
	$(PY) tools/bench_udp.py
