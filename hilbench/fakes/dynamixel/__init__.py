"""Emulated Dynamixel devices: models as data, servo behaviour, and the bus that hosts them."""

from hilbench.fakes.dynamixel.bus import DynamixelBus
from hilbench.fakes.dynamixel.servo import Servo
from hilbench.protocols.dynamixel_models import MODELS, Model, find_model

__all__ = ["DynamixelBus", "MODELS", "Model", "Servo", "find_model"]
