"""The telnet / RFC 2217 codec: framing, escaping, value layouts, garbage."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import rfc2217 as p
from hilbench.protocols.problem import Problem


def _merge(items):
    """Items with adjacent Data joined (chunking may split data, never anything else)."""
    out = []
    for item in items:
        if isinstance(item, p.Data) and out and isinstance(out[-1], p.Data):
            out[-1] = p.Data(out[-1].data + item.data)
        else:
            out.append(item)
    return out


STREAM = (b"AB\xff\xffC"  # data with an escaped 0xFF
          + p.negotiation(p.WILL, p.COM_PORT_OPTION)
          + p.subnegotiation(p.Command.SET_BAUDRATE, p.build_value(p.Command.SET_BAUDRATE, 0x00FF_FFFF))
          + b"\xff\xf3"  # IAC BRK
          + b"tail")


def test_a_stream_decodes_into_items_in_order():
    items = p.TelnetDecoder().feed(STREAM)
    assert items == [
        p.Data(b"AB\xffC"),
        p.Negotiation(p.WILL, p.COM_PORT_OPTION),
        p.Subnegotiation(p.COM_PORT_OPTION, bytes([p.Command.SET_BAUDRATE]) + b"\x00\xff\xff\xff"),
        p.TelnetCommand(p.BRK),
        p.Data(b"tail"),
    ]
    # the baud value's 0xFF bytes were doubled on the wire and come back single
    assert STREAM.count(b"\xff\xff\xff\xff\xff\xff") == 1
    assert p.parse_value(p.Command.SET_BAUDRATE, items[2].body[1:]) == 0x00FF_FFFF


def test_every_split_of_the_stream_gives_the_same_items():
    whole = _merge(p.TelnetDecoder().feed(STREAM))
    for cut in range(1, len(STREAM)):
        dec = p.TelnetDecoder()
        assert _merge(dec.feed(STREAM[:cut]) + dec.feed(STREAM[cut:])) == whole, cut


def test_values_build_and_parse_with_their_layouts():
    assert p.build_value(p.Command.SET_BAUDRATE, 2_000_000) == (2_000_000).to_bytes(4, "big")
    assert p.build_value(p.Command.SET_BAUDRATE + p.SERVER_OFFSET, 57_600) == (57_600).to_bytes(4, "big")
    assert p.build_value(p.Command.SET_CONTROL, p.Control.DTR_OFF) == b"\x09"
    assert p.parse_value(p.Command.SET_DATASIZE, b"\x07") == 7
    assert p.parse_value(p.Command.SET_BAUDRATE, b"\x00\x01") is None  # too short: no value, no exception


def test_modem_state_bits_and_deltas():
    state = p.modem_state(cts=True, dsr=False, ri=False, cd=True)
    assert state == 0x90
    assert p.with_deltas(state, None) == 0x90 | 0x01 | 0x08
    assert p.with_deltas(state, 0x90) == 0x90
    assert p.with_deltas(0x00, 0x90) == 0x09


def test_an_oversized_subnegotiation_is_dropped_and_counted_without_buffering_it():
    dec = p.TelnetDecoder()
    body = bytes([p.COM_PORT_OPTION, 0]) + b"x" * (p.MAX_SUBNEGOTIATION * 4)
    items = dec.feed(b"\xff\xfa" + body + b"\xff\xf0after")
    assert isinstance(items[0], Problem) and items[0].kind == "overlong" and items[0].count >= len(body)
    assert items[-1] == p.Data(b"after")
    assert len(dec._sb) <= p.MAX_SUBNEGOTIATION


def test_a_subnegotiation_that_loses_its_end_is_reported_and_parsing_goes_on():
    items = p.TelnetDecoder().feed(b"\xff\xfa\x2c\x01\x00\xff\xfb\x2cdata")
    assert isinstance(items[0], Problem) and items[0].kind == "unterminated" and items[0].count == 5
    assert items[1:] == [p.Negotiation(p.WILL, p.COM_PORT_OPTION), p.Data(b"data")]


@given(st.lists(st.binary(max_size=64), max_size=20))
def test_garbage_never_raises_and_data_survives_escaping(chunks):
    dec = p.TelnetDecoder()
    for chunk in chunks:
        dec.feed(chunk)
    # whatever came before, escaped data after a clean break comes back intact
    payload = b"".join(chunks)
    fresh = p.TelnetDecoder()
    assert _merge(fresh.feed(p.escape(payload))) == ([p.Data(payload)] if payload else [])
