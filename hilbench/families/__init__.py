"""hilbench's built-in device families, each a plug-in registered like an outside package's.

Each module holds one :class:`~hilbench.bench.family.DeviceFamily` (``FAMILY``),
named in the ``hilbench.families`` entry-point group of ``pyproject.toml``:
its profile schema, how it builds its fakes on an endpoint, its manifest
entries and control commands. A family imports its fakes, protocols and
transports, and the bench layer's base classes; nothing imports a family
but the registry.
"""
