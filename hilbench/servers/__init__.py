"""Built-in servers (``hilbench emulate --serve NAME``); see :mod:`hilbench.bench.server`."""
