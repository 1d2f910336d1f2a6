"""hilbench and labgrid: configuration for served benches, drivers, and benches taken from labgrid targets.

- :mod:`hilbench.labgrid.config`: exporter configuration and environment files
  from a bench manifest (no labgrid needed).
- :mod:`hilbench.labgrid.drivers`: ``BenchControlDriver`` and ``HilbenchStrategy``
  on labgrid's ConsoleProtocol, any bench's (needs labgrid);
- a family's driver for its bus, in the family's own module
  (:mod:`hilbench.labgrid.dynamixel`: ``DynamixelDriver``), named by its bus
  kind (:meth:`~hilbench.bench.bus.BusKind.labgrid_driver`).
- :mod:`hilbench.labgrid.remote`: a bench found through a labgrid target (a
  place or an environment file), used by the pytest plugin (needs labgrid).
"""
