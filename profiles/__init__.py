"""Bench profiles shipped with hilbench (installed as the ``hilbench.profiles`` package)."""

#: The bundled profile a bench starts from when none is named (``hilbench emulate``, ``demo``, ``bench:``);
#: here rather than in :mod:`hilbench.bench.profile` so a verb's ``--help`` can say it without importing the bench.
DEFAULT_PROFILE = "wolfgang"
