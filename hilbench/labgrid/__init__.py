"""hilbench and labgrid: configuration for served benches, drivers, and benches taken from labgrid targets.

- :mod:`hilbench.labgrid.config`: exporter configuration and environment files
  from a bench manifest (no labgrid needed).
- :mod:`hilbench.labgrid.drivers`: ``DynamixelDriver``, ``BenchControlDriver``
  and ``HilbenchStrategy`` on labgrid's ConsoleProtocol (needs labgrid).
- :mod:`hilbench.labgrid.remote`: a bench found through a labgrid target (a
  place or an environment file), used by the pytest plugin (needs labgrid).
"""
