"""A generic control-table board (``model = "control-table"``) on a Dynamixel bus, driven by the official SDK."""

from __future__ import annotations

import pytest

from hilbench.bench.checks import ProfileError
from hilbench.bench.profile import parse_profile

BOARD = """
schema = 1
description = "a lab's foot sensor beside a servo"

[endpoints.dxl]
type = "pty"
protocol = "dynamixel"
baud = 1_000_000

[[devices]]
model = "XM430-W350"
id = 1

[[devices]]
model = "control-table"
id = 101
name = "foot"
model_number = 0xAFFE
firmware = 3
registers = [
  { address = 36, size = 4, name = "Front Left", access = "R", value = 120 },
  { address = 40, size = 2, value = 7, signed = true },
  { address = 42, size = 1, access = "RW", value = 0 },
]
"""


@pytest.fixture
def board(hilbench_bench, tmp_path, patient_sdk):
    import dynamixel_sdk as sdk

    path = tmp_path / "board.toml"
    path.write_text(BOARD)
    bench = hilbench_bench(str(path), port_state=False)
    port = sdk.PortHandler(bench.endpoint().path)
    assert port.openPort() and port.setBaudRate(1_000_000)
    yield bench, port, sdk.PacketHandler(2.0), sdk
    port.closePort()


def test_the_board_answers_with_its_registers(board):
    bench, port, ph, sdk = board
    assert ph.ping(port, 101) == (0xAFFE, sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 101, 6) == (3, sdk.COMM_SUCCESS, 0)  # the firmware version
    assert ph.read4ByteTxRx(port, 101, 36) == (120, sdk.COMM_SUCCESS, 0)
    data, result, error = ph.readTxRx(port, 101, 36, 7)  # a block across registers, as hosts read
    assert (bytes(data), result, error) == (bytes([120, 0, 0, 0, 7, 0, 0]), sdk.COMM_SUCCESS, 0)
    assert ph.write2ByteTxRx(port, 101, 40, 0xFFFE) == (sdk.COMM_SUCCESS, 0)  # -2, signed
    assert ph.read2ByteTxRx(port, 101, 40)[0] == 0xFFFE
    assert bench.device(101).get("register_40") == -2
    assert ph.ping(port, 1)[0] == 1020  # the servo beside it


def test_writes_the_board_refuses(board):
    _bench, port, ph, sdk = board
    assert ph.write4ByteTxRx(port, 101, 36, 5) == (sdk.COMM_SUCCESS, 7)  # read-only: Access Error
    assert ph.write1ByteTxRx(port, 101, 40, 1) == (sdk.COMM_SUCCESS, 5)  # half a register: Data Length Error
    assert ph.write1ByteTxRx(port, 101, 50, 1) == (sdk.COMM_SUCCESS, 7)  # past the table
    assert ph.read4ByteTxRx(port, 101, 36) == (120, sdk.COMM_SUCCESS, 0)


@pytest.mark.parametrize(("change", "message"), [
    ("{ address = 36, size = 3 }", r"devices\[1\]\.registers\[0\]\.size: expected 1, 2 or 4, got 3"),
    ("{ address = 36, size = 4 }, { address = 38, size = 2 }", r"registers\[1\]\.address: overlaps registers\[0\]"),
    ("{ address = 1023, size = 2 }", r"registers\[0\]\.address: the register ends past the table \(1024 bytes\)"),
    ("{ address = 0, size = 2 }", r"registers\[0\]\.address: 0 and 1 hold the Model Number"),
    ("{ address = 36, size = 1, value = 300 }", r"registers\[0\]\.value: expected an integer 0\.\.255, got 300"),
    ("{ address = 36, size = 1, colour = 1 }", r"registers\[0\]\.colour: unknown key"),
])
def test_profile_errors_name_the_register(change, message):
    import tomllib

    text = BOARD.replace(BOARD[BOARD.index("registers = ["):], f"registers = [{change}]\n")
    with pytest.raises(ProfileError, match=message):
        parse_profile(tomllib.loads(text), "board.toml")


def test_board_keys_only_on_boards():
    import tomllib

    text = BOARD.replace('model = "XM430-W350"\nid = 1', 'model = "XM430-W350"\nid = 1\nmodel_number = 5')
    with pytest.raises(ProfileError, match=r'devices\[0\]\.model_number: only for model = "control-table" boards'):
        parse_profile(tomllib.loads(text), "board.toml")
