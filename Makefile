# The two commands of the README: `make demo` and `make test`.
# Both create .venv and install hilbench with its test extra on first use.
VENV ?= .venv
PYTHON ?= python3
PY := $(VENV)/bin/python

.PHONY: demo test lint bench install install-robots

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $@

install: $(VENV)/.installed

# The robots' own software for the real-client tests (pytest -m robots; skipped without it): pypot and
# the Poppy creatures from the `robots` extra, and LeRobot's motor buses and robot classes. LeRobot is
# installed without its dependencies: they are a machine-learning stack (torch, datasets, ...) of
# several GB that its servo code does not use (tests/robots/lerobot_client.py says how it is loaded).
install-robots: $(VENV)/.robots

$(VENV)/.robots: $(VENV)/.installed
	$(PY) -m pip install -q -e '.[test,robots]'
	$(PY) -m pip install -q --no-deps 'lerobot==0.4.4'
	touch $@

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
