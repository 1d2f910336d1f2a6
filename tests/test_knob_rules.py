"""Fault knobs: one set of rules (hilbench.rules) for profiles, control commands and command lines."""

from __future__ import annotations

import argparse

import pytest

from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlError
from hilbench.bench.knobs import check_fault_table, check_knobs
from hilbench.errors import UsageError
from hilbench.families import canopen_board, dynamixel, feetech, rplidar, scip2, sick_lms200, stm32_rover
from hilbench.families.micro_ros_agent import FAULT_RULES as AGENT_RULES
from hilbench.rules import FAULT_COUNT, SWITCH, Rule, RuleError, Switch
from hilbench.transports.can_medium import FAULT_RULES as BUS_RULES


def test_a_switch_takes_booleans_and_their_words():
    assert SWITCH.check(True) is True and SWITCH.ok(False)
    assert not SWITCH.ok(1) and not SWITCH.ok("true")
    with pytest.raises(RuleError, match="expected true or false, got 1"):
        SWITCH.check(1)
    assert [SWITCH.parse(t) for t in ("true", "ON", "yes", "1", "false", "off", "No", "0")] == [True] * 4 + [False] * 4
    with pytest.raises(argparse.ArgumentTypeError, match="expected true or false, got 'maybe'"):
        SWITCH("maybe")


def test_any_number_keeps_the_range_of_a_count():
    loose = FAULT_COUNT.any_number()
    assert loose.ok(2.5) and not FAULT_COUNT.ok(2.5) and not loose.ok(-1.0) and not loose.ok(True)
    assert Rule(float, 0, 1).any_number().expected == "a number 0..1" and SWITCH.any_number() is SWITCH


def test_every_family_states_its_knobs_as_rules():
    tables = [dynamixel.FAULT_RULES, feetech.SERVO_FAULT_RULES, canopen_board.FAULT_RULES, BUS_RULES, AGENT_RULES,
              rplidar.FAULTS, sick_lms200.FAULTS, scip2.FAULTS, stm32_rover.FAULT_RULES]
    for table in tables:
        assert table and all(isinstance(rule, Rule | Switch) for rule in table.values()), table
    assert set(dynamixel.FAULT_RULES) == set(feetech.SERVO_FAULT_RULES) | {"hardware_error"}  # the servo knobs + one
    assert dynamixel.FAULT_RULES["hardware_error"].expected == "an integer 0..61"


def test_one_table_checks_a_profile_a_control_command_and_a_command_line():
    rules = rplidar.FAULTS
    c = Checker("bench.toml")
    assert check_fault_table(c, "devices[0].faults", {"stall": True, "corrupt_rate": 0.5}, rules) == \
        {"stall": True, "corrupt_rate": 0.5}
    with pytest.raises(UsageError, match=r"bench.toml: devices\[0\].faults.health_status: expected an integer 0..2, got 3"):
        check_fault_table(c, "devices[0].faults", {"health_status": 3}, rules)
    with pytest.raises(UsageError, match=r"devices\[0\].faults.sticky: expected true or false, got 1"):
        check_fault_table(c, "devices[0].faults", {"sticky": 1}, rules)
    with pytest.raises(ControlError, match="fault knob corrupt_rate: expected a number 0..1, got 2"):
        check_knobs({"corrupt_rate": 2}, rules)
    with pytest.raises(ControlError, match="unknown fault knob 'warp' .expected one of: stall, health_status"):
        check_knobs({"warp": 1}, rules)
    # a client that sends every value as a float (hilbench board fault) may turn a count knob
    assert check_knobs({"health_status": 1.0}, rules, whole_counts=False) == {"health_status": 1.0}
    with pytest.raises(ControlError, match="expected an integer 0..2, got 1.0"):
        check_knobs({"health_status": 1.0}, rules)
    # the command line checks with the same rules before sending, as a usage error (exit status 2)
    with pytest.raises(RuleError, match="fault knob drop_rate: expected a number 0..1, got 2"):
        stm32_rover.check_fault_knobs({"drop_rate": 2})


def test_the_can_board_family_and_its_fake_name_the_same_knobs():
    """The family checks the knobs the fake turns (the fake is imported only when a bench runs)."""
    from hilbench.fakes.canopen.rover import ROVER_FAULT_KEYS

    assert tuple(canopen_board.FAULT_RULES) == ROVER_FAULT_KEYS
