"""The labgrid set needs labgrid, which replaces pyserial's ``serial`` package with pyserial-labgrid's:
``make test-labgrid`` runs it in a venv of its own (``.ci/run`` does too). The main suite, whose venv has
no labgrid, leaves the file out instead of reporting skips."""

import importlib.util

collect_ignore = [] if importlib.util.find_spec("labgrid") else ["test_labgrid.py"]
