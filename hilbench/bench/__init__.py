"""The bench layer: profiles, device families, running benches, their manifest and control channel.

- :mod:`~hilbench.bench.profile`: reading and checking profiles (the frame; families check the rest);
- :mod:`~hilbench.bench.bus`: :class:`BusKind`, what an endpoint's bus is (keyed by its ``protocol``);
- :mod:`~hilbench.bench.family`: :class:`DeviceFamily`, what a family of devices is to a bench (keyed by model),
  and :class:`FamilyAccess`, its devices' typed lookups on a running bench (``bench.family(name)``);
- :mod:`~hilbench.bench.bench`: :class:`Bench` and its :class:`Endpoint` s;
- :mod:`~hilbench.bench.manifest`: the manifest file other programs read;
- :mod:`~hilbench.bench.control`: the control channel for other processes.

The names below are imported from their modules when first used (PEP 562), not with the package: programs
that only read a manifest (``hilbench monitor MANIFEST``, ``hilbench run``) import
:mod:`~hilbench.bench.manifest` without the profile loader, the families and the world.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hilbench.exports import lazy_exports

if TYPE_CHECKING:
    from hilbench.bench.bench import Bench, Endpoint
    from hilbench.bench.bus import BusKind
    from hilbench.bench.checks import Checker, ProfileError
    from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess
    from hilbench.bench.profile import DEFAULT_PROFILE, EndpointSpec, Profile, load_profile

#: Each public name and the module that defines it.
_HOMES = {"Bench": "bench", "Endpoint": "bench", "BusKind": "bus", "Checker": "checks", "ProfileError": "checks",
          "DeviceFamily": "family", "DeviceSpec": "family", "FamilyAccess": "family",
          "DEFAULT_PROFILE": "profile", "EndpointSpec": "profile", "Profile": "profile", "load_profile": "profile"}

__all__ = ["DEFAULT_PROFILE", "Bench", "BusKind", "Checker", "DeviceFamily", "DeviceSpec", "Endpoint", "EndpointSpec",
           "FamilyAccess", "Profile", "ProfileError", "load_profile"]
__getattr__, __dir__ = lazy_exports(__name__, _HOMES)
