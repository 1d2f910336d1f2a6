"""``hilbench run``: unmodified clients get a serial adapter's semantics on a bench's ptys.

A pseudo-terminal has no modem lines (TIOCM* ioctls fail with ENOTTY), ignores
BREAK, and ``tcflush(TCOFLUSH)`` on it discards bytes the bench has not read.
A client run under ``hilbench run`` has those calls, on the bench's ptys only,
answered by the bench's port-state server (:mod:`hilbench.bench.port_state_server`):

- ``shim.c``, an LD_PRELOAD library built with the
  system's C compiler on first use (:mod:`hilbench.run.build`), for every
  dynamically linked program (Python, C, C++); ``vclock.c`` in the same library
  puts the client on a virtual-time bench's clock (dormant without one; its page
  is described in :mod:`hilbench.run.vclock_page`);
- :mod:`hilbench.run.pyserial_shim`, a patch of pyserial loaded through a
  ``sitecustomize`` where no compiler exists (or ``HILBENCH_RUN_SHIM=python``);
  the pytest plugin applies it in-process for fixture benches.

:func:`~hilbench.run.environment.run_environment` turns manifests into the
environment; the ``hilbench run`` verb (:mod:`hilbench.cli.run`) execs the client in it.
"""

from hilbench.run.build import ShimBuildError, shim_library
from hilbench.run.environment import BenchPorts, manifest_paths, read_bench, run_environment

__all__ = ["BenchPorts", "ShimBuildError", "manifest_paths", "read_bench", "run_environment", "shim_library"]
