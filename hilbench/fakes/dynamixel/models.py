"""Dynamixel device models, as the fakes have always imported them.

The tables moved to :mod:`hilbench.protocols.dynamixel_models` so that the bus
monitor can read them without importing the fakes (DESIGN.md §2); this module
re-exports that one definition.
"""

from hilbench.protocols.dynamixel_models import *  # noqa: F403
from hilbench.protocols.dynamixel_models import (  # noqa: F401  (names used through this path)
    ALIASES,
    BAUD_CODES,
    BAUD_TO_CODE,
    MODELS,
    MODELS_BY_NUMBER,
    Field,
    Model,
    find_model,
    model_names,
)
