"""The virtual clock's shared page, as ``hilbench run``'s shim (``vclock.c``) sees it: the numbers are
:mod:`hilbench.bench.clock_page`'s (the bench's lockstep creates the page; this is the client side's name)."""

from hilbench.bench.clock_page import *  # noqa: F403
from hilbench.bench.clock_page import __all__  # noqa: F401
