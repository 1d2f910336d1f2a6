# The two commands of the README: `make demo` and `make test`.
# Both create .venv and install hilbench with its test extra on first use.
VENV ?= .venv
PYTHON ?= python3
PY := $(VENV)/bin/python

LGVENV ?= .venv-labgrid

# Python may cache bytecode (in the git-ignored __pycache__/) even where the environment says not to: the
# tests start hundreds of `hilbench` processes, and compiling the package from source in each one, and every
# test module at collection, cost about a quarter of a minute per run.
unexport PYTHONDONTWRITEBYTECODE

.PHONY: demo test test-slow test-labgrid lint bench install install-robots docs

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $@

# dynamixel-sdk 3.x (what ROS packages and most robots run; 4.x is our dependency) beside it, for the
# tests and benchmarks of what its clearPort() does before every packet: ser.flush(), a tcdrain.
SDK3 := $(VENV)/dynamixel-sdk-3
$(SDK3)/.installed: $(VENV)/.installed
	$(PY) -m pip install -q --no-deps --upgrade --target $(SDK3) 'dynamixel-sdk==3.8.4'
	touch $@

install: $(VENV)/.installed $(SDK3)/.installed

# The robots' own software for the real-client tests (pytest -m robots; skipped without it): pypot and
# the Poppy creatures from the `robots` extra, and LeRobot's motor buses and robot classes. LeRobot is
# installed without its dependencies: they are a machine-learning stack (torch, datasets, ...) of
# several GB that its servo code does not use (tests/robots/lerobot_client.py says how it is loaded).
install-robots: $(VENV)/.robots

$(VENV)/.robots: $(VENV)/.installed
	$(PY) -m pip install -q -e '.[test,robots]'
	$(PY) -m pip install -q --no-deps 'lerobot==0.4.4'
	touch $@

# labgrid pulls pyserial-labgrid, which installs its own `serial` package over pyserial's; it gets a
# venv of its own, where pyserial-labgrid's files are made the installed ones, so the serial tests
# run once with each `serial`.
$(LGVENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(LGVENV)
	$(LGVENV)/bin/python -m pip install -q --upgrade pip
	$(LGVENV)/bin/python -m pip install -q -e '.[test,labgrid]'
	$(LGVENV)/bin/python -m pip install -q --no-deps --force-reinstall pyserial-labgrid
	touch $@

demo: $(VENV)/.installed
	$(VENV)/bin/hilbench demo

# The README's test command: lint, then every test but the slow real-client set (five to six minutes).
test: $(VENV)/.installed $(SDK3)/.installed
	$(PY) -m ruff check hilbench tests tools
	$(PY) -m pytest -q -m "not slow"

# The slow real-client set (`slow` marker): clients built from C sources, published scanner clients,
# Cyclone DDS, CAN tools in a terminal, the robots' own software. .ci/run runs it after `make test`.
test-slow: $(VENV)/.robots $(SDK3)/.installed
	$(PY) -m pytest -q -m slow

# The slow labgrid set (real labgrid-coordinator/-exporter/-client) and the serial tests again, under
# pyserial-labgrid's `serial`. .ci/run runs it after `make test`.
test-labgrid: $(LGVENV)/.installed
	$(LGVENV)/bin/python -c "import serial.rfc2217 as r, inspect; assert 'skipped' in inspect.getsource(r), 'serial is not pyserial-labgrid'"
	$(LGVENV)/bin/python -m pytest -q -p no:cacheprovider tests/labgrid tests/transports/test_rfc2217.py \
		tests/fakes/test_dynamixel_sdk.py tests/test_cli.py

# The documentation site (docs/, Sphinx): the API reference is generated from the docstrings into
# docs/api/_generated/ on every build; every warning (a broken cross-reference too: -n) fails it.
# Open docs/_build/html/index.html. .ci/run runs it after `make test`.
$(VENV)/.docs: $(VENV)/.installed
	$(PY) -m pip install -q -e '.[docs]'
	touch $@

# The API pages are generated afresh each time: a module moved or removed leaves no stale page behind.
docs: $(VENV)/.docs
	rm -rf docs/api/_generated
	$(PY) -m sphinx -W --keep-going -n -q -b html docs docs/_build/html

bench: $(VENV)/.installed $(SDK3)/.installed
	$(PY) tools/bench_dynamixel.py
	$(PY) tools/bench_monitor.py
	$(PY) tools/bench_board.py
	$(PY) tools/bench_profiler.py
	$(PY) tools/bench_remote.py
	$(PY) tools/bench_run.py
	$(PY) tools/bench_lidar.py
	$(PY) tools/bench_can.py
	$(PY) tools/bench_udp.py
	$(PY) tools/bench_startup.py
