"""hilbench's built-in device families, each a plug-in registered like an outside package's.

Each module holds one :class:`~hilbench.bench.family.DeviceFamily` (``FAMILY``),
named in the ``hilbench.families`` entry-point group of ``pyproject.toml``:
its models and device keys, how it builds its fakes on an endpoint, its
manifest entries and control commands; and, where the family brings its own
bus, a :class:`~hilbench.bench.bus.BusKind` (``BUS_KIND``, in
``hilbench.bus_kinds``): the endpoint keys, medium and shared bus object of its
endpoint ``protocol``, which other families' devices may join too. A family imports its fakes, protocols and
transports, and the bench layer's base classes; nothing imports a family
but the registry.
"""
