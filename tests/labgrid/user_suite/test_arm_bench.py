"""A user's bench test, written once: it runs against a local bench and, unchanged, against a remote one.

``pytest tests/labgrid/user_suite`` starts the arm bench here; ``pytest --lg-env ENV.yaml
--hilbench-labgrid tests/labgrid/user_suite`` takes it from a labgrid target (a place acquired through a
coordinator, or a ``hilbench labgrid env`` file). tests/labgrid/test_labgrid.py runs it all three ways.
"""

from __future__ import annotations

import dynamixel_sdk as sdk
import pytest

pytestmark = pytest.mark.hilbench_profile("arm")


def test_the_sdk_pings_and_syncs_the_arm(bench):
    port = sdk.PortHandler(bench.endpoint().path)  # the official SDK, unmodified, on a path
    assert port.openPort() and port.setBaudRate(1_000_000)
    ph = sdk.PacketHandler(2.0)
    try:
        assert ph.ping(port, 5) == (1060, sdk.COMM_SUCCESS, 0)  # the gripper
        reader = sdk.GroupSyncRead(port, ph, 132, 4)  # Present Position
        for i in (1, 2, 3, 4):
            assert reader.addParam(i)
        assert reader.txRxPacket() == sdk.COMM_SUCCESS
        assert all(reader.isAvailable(i, 132, 4) for i in (1, 2, 3, 4))
    finally:
        port.closePort()


def test_the_manifest_names_the_bench(bench):
    manifest = bench.manifest()
    assert manifest["name"] == "arm"
    assert [d["id"] for d in manifest["devices"]] == [1, 2, 3, 4, 5]
