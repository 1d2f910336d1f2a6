"""What a decoder throws away, reported instead of raised: one :class:`~hilbench.protocols.problem.Problem` type for every decoder.

Decoders never raise on garbage: they resynchronise, count what they dropped
and put a :class:`Problem` among their items where it happened, so a consumer
tells good items from damage with one test (``type(item) is Problem``) and
reads one set of fields whatever the protocol. ``kind`` is a short word the
decoder documents; the other fields are filled where the decoder has them
(their defaults otherwise):

- :class:`hilbench.protocols.dynamixel.Decoder`: ``crc``, ``truncated``,
  ``bad_length``, ``stuffing``; raw, t, detail.
- :class:`hilbench.protocols.dynamixel_protocol1.Decoder1` (Protocol 1.0 and
  Feetech): ``checksum``, ``bad_length``, ``truncated``; raw, t.
- :class:`hilbench.protocols.rplidar.RequestDecoder` and
  :class:`~hilbench.protocols.rplidar.ResponseDecoder`: ``garbage``,
  ``checksum``, ``descriptor``, ``banner``, ``truncated``; raw, detail.
- :class:`hilbench.protocols.scip.RequestDecoder` and
  :class:`~hilbench.protocols.scip.ReplyDecoder`: ``overlong``, ``garbage``;
  raw, detail.
- :class:`hilbench.protocols.sick_lms200.Decoder`: ``garbage``, ``crc``,
  ``length``; raw, detail.
- :class:`hilbench.protocols.rfc2217.TelnetDecoder`: ``stray``, ``overlong``,
  ``empty``, ``unterminated`` (subnegotiations); count (bytes), detail.
- :class:`hilbench.protocols.tracestamp.TextDecoder`: ``unreadable`` (a line no
  format fits, one problem per line); raw (its first 80 bytes if overlong), detail.
- :class:`hilbench.protocols.tracestamp_binary.WordDecoder`: ``broken_word``,
  ``reserved_id``, ``unknown_op``; count (words), t_us.
- :func:`hilbench.protocols.vel2d.decode`: ``length``, ``crc``; raw, expected,
  got, detail (the firmware's log message).
- :func:`hilbench.protocols.board_can.check_setpoint` (a check, not a stream):
  ``length``, ``checksum``; raw, expected, got.
"""

from __future__ import annotations

from typing import NamedTuple


class Problem(NamedTuple):
    """Something a decoder dropped or a check refused (the module's docstring lists who sets what).

    A tuple, cheap to make on a decoder's hot path. Give ``kind``, ``raw`` and ``detail`` by position, the
    other fields by name; read fields by name (the tuple may grow).
    """

    #: What went wrong, a word the decoder documents (``crc``, ``truncated``, ``garbage``, ...).
    kind: str
    #: The bytes dropped (a decoder that bounds what it keeps gives their start).
    raw: bytes = b""
    #: A short explanation for people (``"mismatched checksum"``, a firmware's log message).
    detail: str = ""
    #: When, in the time base of the ``t`` the decoder was fed (seconds); 0.0 if it had none.
    t: float = 0.0
    #: How many bytes or words the problem stands for where ``raw`` does not hold them (telnet's dropped bytes,
    #: damaged trace words); 0 where ``raw`` is the whole of it (a packet, a line).
    count: int = 0
    #: The check value computed from the bytes (a CRC or checksum), where a decoder compares one.
    expected: int = 0
    #: The check value the bytes carried.
    got: int = 0
    #: A trace's own time in integer microseconds (a float would round it), None where unknown.
    t_us: int | None = None


__all__ = ["Problem"]
