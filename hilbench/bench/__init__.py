"""The bench layer: profiles, device families, running benches, their manifest and control channel.

- :mod:`~hilbench.bench.profile`: reading and checking profiles (the frame; families check the rest);
- :mod:`~hilbench.bench.bus`: :class:`BusKind`, what an endpoint's bus is (keyed by its ``protocol``);
- :mod:`~hilbench.bench.family`: :class:`DeviceFamily`, what a family of devices is to a bench (keyed by model),
  and :class:`FamilyAccess`, its devices' typed lookups on a running bench (``bench.family(name)``);
- :mod:`~hilbench.bench.bench`: :class:`Bench` and its :class:`Endpoint` s;
- :mod:`~hilbench.bench.manifest`: the manifest file other programs read;
- :mod:`~hilbench.bench.control`: the control channel for other processes.
"""

from hilbench.bench.bench import Bench, Endpoint
from hilbench.bench.bus import BusKind
from hilbench.bench.checks import Checker, ProfileError
from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess
from hilbench.bench.profile import DEFAULT_PROFILE, EndpointSpec, Profile, load_profile

__all__ = ["DEFAULT_PROFILE", "Bench", "BusKind", "Checker", "DeviceFamily", "DeviceSpec", "Endpoint", "EndpointSpec",
           "FamilyAccess", "Profile", "ProfileError", "load_profile"]
