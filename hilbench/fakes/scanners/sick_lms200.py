"""An emulated SICK LMS 200 on a serial line: telegrams with ACK/NAK, link speeds, modes, variants, scans.

Behaviour (spec sheet laser_scanners.md §2):

- the link starts at 9600 baud (power-up and RESET); host bytes at another rate
  than the current one are framing garbage; a telegram with a bad CRC is
  answered with NAK (15), a good one with ACK (06) before any reply;
- mode 40/41/42/48 changes the link speed *after* the A0 reply, which still
  goes out at the old speed; mode 24 streams B0 scans, mode 25 (values on
  request) stops the stream after the telegram in progress; installation mode
  (00) needs the password ``SICK_LMS``; refused modes answer A0 01;
- 30 01 answers with the next scan that starts after the request (mirror
  wait); 3B sets the variant (100°/180°, 1°/0.5°/0.25°; BB 01 or BB 00 with
  the current variant); 74/77 read and write the configuration block (units:
  mm or cm; writing needs installation mode); 3A and 31 describe the unit;
  10 resets (91 at once, 90 when ready, back to 9600 baud);
- scans are measured on a 75 Hz mirror clock from the right (0°) to the left,
  the sensor looking along 90°; every byte leaves no faster than the baud
  rate allows (10 bits a byte).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import numpy as np

from hilbench.fakes.scanners.base import Scanner
from hilbench.fakes.scanners.uart import UartTx
from hilbench.fakes.scene import Pose, RangeModel, Scene
from hilbench.fakes.world import World
from hilbench.protocols import sick_lms200 as lms

#: Processing time before a reply telegram starts (after the ACK).
REPLY_DELAY = 0.002
#: Time from RESET to the "power on" (90) telegram.
RESET_TIME = 0.3
TYPE_STRING = b"LMS200;30106"
SOFTWARE = b"V02.10 "


@dataclass
class LmsFaults:
    """Fault knobs (spec §2.9)."""

    nak_next: int = 0  # answer the next N good telegrams with NAK
    no_ack: bool = False  # never send the ACK byte
    bad_crc_rate: float = 0.0  # reply telegrams with a wrong CRC
    refuse_modes: bool = False  # every mode change answered A0 01
    status: int = lms.STATUS_OK
    truncate_next: int = 0  # the next N B0 telegrams lose their tail
    ignore_stop_once: bool = False  # streaming goes on for one more scan after mode 25
    seed: int = 0


@dataclass
class LmsConfig:
    angle: int = 180
    resolution: int = 50
    units_mm: bool = True
    no_echo: int = 8191  # the value reported when nothing returns (top of the 13-bit range)
    address: int = 0
    faults: LmsFaults = field(default_factory=LmsFaults)


class SickLms200(Scanner):
    """The emulated LMS 200."""

    def __init__(self, name: str, scene: Scene | World, pose: Pose, model: RangeModel | None = None,
                 config: LmsConfig | None = None, *, t0: float | None = None, body: str | None = None) -> None:
        super().__init__(name, scene, pose, model or RangeModel(0.0, 80.0, 0.01, 0.0), t0=t0, body=body)
        self.config = config or LmsConfig()
        self.faults = self.config.faults
        self.frng = np.random.default_rng(self.faults.seed + 7)
        lms.layouts()  # (made now, not on a client's first request: replies are built with them)
        self.baud = lms.POWER_UP_BAUD
        self.mode = lms.Mode.POLLED
        self.installation = False
        self.angle = self.config.angle
        self.resolution = self.config.resolution
        self.units_mm = self.config.units_mm
        self.config_block = bytearray(lms.CONFIG_SIZE)
        self.config_block[lms.CONFIG_UNITS] = 1 if self.units_mm else 0
        self.decoder = lms.Decoder(handshakes=False)
        self.tx: UartTx | None = None
        self.streaming = False
        self.stream_epoch = 0
        self.telegram_index = 0
        self.scans_sent = 0
        self.baud_mismatch = 0
        self.ready_at = 0.0

    def attach(self, medium) -> None:
        super().attach(medium)
        self.tx = UartTx(self.port, self.baud, counters=self.counters)

    # ------------------------------------------------------------------ geometry

    def directions(self, sensor_deg: np.ndarray, heading: np.ndarray | float) -> np.ndarray:
        """LMS angles run from the right (0°) to the left (180°); straight ahead is 90°."""
        return heading + np.radians(np.asarray(sensor_deg, float) - 90.0)

    def beam_times(self, t_start: float, angles: np.ndarray) -> np.ndarray:
        """When each beam is taken: the mirror turns at 75 Hz and passes 0°..180° in half a turn; finer
        resolutions interlace beams of successive turns (beam k on turn k mod turns)."""
        turns = lms.REVOLUTIONS[self.resolution]
        k = np.arange(len(angles))
        return t_start + (np.asarray(angles) / 360.0 + k % turns) * lms.MIRROR_PERIOD

    def beam_angles(self) -> np.ndarray:
        n = lms.VARIANTS[(self.angle, self.resolution)]
        start = 0.0 if self.angle == 180 else 40.0
        return start + np.arange(n) * self.resolution / 100.0

    # ------------------------------------------------------------------ host bytes

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        if baud is not None and baud != self.baud:
            self.baud_mismatch += len(data)
            return
        for item in self.decoder.feed(data):
            if isinstance(item, lms.Frame):
                if item.is_reply or item.address != self.config.address:
                    continue
                self.note_request(item.name)
                self.handle(item, t)
            elif item.kind == "crc":
                self.counters["bad_crc"] += 1
                self._send(bytes([lms.NAK]), t)
            else:
                self.counters[f"rx_{item.kind}"] += 1

    # ------------------------------------------------------------------ replies

    def _send(self, data: bytes, t: float) -> float:
        return self.tx.send(data, t) if self.tx is not None else t

    def _reply(self, cmd: int, data: bytes, t: float, *, status: int | None = None) -> float:
        st = self.faults.status if status is None else status
        tel = lms.reply(cmd, data, st, self.config.address)
        if self.faults.bad_crc_rate and self.frng.random() < self.faults.bad_crc_rate:
            tel = tel[:-1] + bytes([tel[-1] ^ 0xFF])
            self.counters["bad_crc_sent"] += 1
        return self._send(tel, t + REPLY_DELAY)

    def handle(self, req: lms.Frame, t: float) -> None:
        """Answer one request telegram received at ``t``."""
        f = self.faults
        if t < self.ready_at:
            return  # still booting after a reset
        if f.nak_next:
            f.nak_next -= 1
            self._send(bytes([lms.NAK]), t)
            return
        if not f.no_ack:
            self._send(bytes([lms.ACK]), t)
        cmd, d = req.cmd, req.data
        if cmd == lms.Cmd.MODE and d:
            self._mode(d, t)
        elif cmd == lms.Cmd.SCAN:
            if d[:1] == b"\x01":
                t_start = self._next_scan_start(t)
                self._send_scan(t_start, t_ready=t_start + self._scan_duration())
            else:
                self._reply(0x92, b"", t)
        elif cmd == lms.Cmd.STATUS:
            self._reply(0xB1, self.status_block(), t)
        elif cmd == lms.Cmd.TYPE:
            self._reply(0xBA, TYPE_STRING, t)
        elif cmd == lms.Cmd.VARIANT and len(d) >= 4:
            angle, res = struct.unpack_from("<HH", d)
            ok = (angle, res) in lms.VARIANTS
            if ok:
                self.angle, self.resolution = angle, res
                self._stop_stream()
            self._reply(0xBB, lms.VariantReply.build({"accepted": int(ok), "angle": self.angle,
                                                      "resolution": self.resolution}), t)
        elif cmd == lms.Cmd.READ_CONFIG:
            self._reply(0xF4, bytes(self.config_block), t)
        elif cmd == lms.Cmd.WRITE_CONFIG:
            if self.installation and len(d) == lms.CONFIG_SIZE:
                self.config_block[:] = d
                self.units_mm = d[lms.CONFIG_UNITS] == 1
                self._reply(0xF7, b"\x01" + bytes(self.config_block), t)
            else:
                self._reply(0xF7, b"\x00" + bytes(self.config_block), t)
        elif cmd == lms.Cmd.RESET:
            self._reset(t)
        else:
            self._reply(lms.REPLY_INVALID, b"", t)

    def _mode(self, d: bytes, t: float) -> None:
        mode = d[0]
        refuse = self.faults.refuse_modes
        if mode in lms.BAUD_MODES and not refuse:
            end = self._reply(0xA0, b"\x00", t)
            new = lms.BAUD_MODES[mode]
            # The reply leaves at the old speed; the LMS switches once it is out.
            self.port.call_at(end, lambda: self._set_baud(new))
            return
        if mode == lms.Mode.INSTALLATION:
            ok = d[1:9] == lms.PASSWORD and not refuse
            self.installation = ok or self.installation
            self._reply(0xA0, b"\x00" if ok else b"\x01", t)
            return
        if mode in (lms.Mode.POLLED, lms.Mode.CONTINUOUS, lms.Mode.DIAGNOSTIC) and not refuse:
            self.installation = False
            end = self._reply(0xA0, b"\x00", t)
            self.mode = mode
            if mode == lms.Mode.CONTINUOUS:
                if not self.streaming:
                    self.streaming = True
                    self.stream_epoch += 1
                    self._schedule_stream(end)
            else:
                if self.faults.ignore_stop_once and self.streaming:
                    self.faults.ignore_stop_once = False
                    epoch = self.stream_epoch
                    self.port.call_at(end + 0.2, lambda: self._stop_stream() if epoch == self.stream_epoch
                                      else None)
                else:
                    self._stop_stream()
            return
        self._reply(0xA0, b"\x01", t)

    def _set_baud(self, baud: int) -> None:
        self.baud = baud
        if self.tx is not None:
            self.tx.baud = baud
        self.counters["baud_changes"] += 1

    def _reset(self, t: float) -> None:
        self._stop_stream()
        end = self._reply(lms.REPLY_RESET, b"", t)
        self.ready_at = end + RESET_TIME

        def ready() -> None:
            self._set_baud(lms.POWER_UP_BAUD)
            self.mode = lms.Mode.POLLED
            self.installation = False
            self._reply(lms.REPLY_POWER_ON, SOFTWARE, self.now())

        self.port.call_at(self.ready_at, ready)

    # ------------------------------------------------------------------ scans

    def _scan_duration(self) -> float:
        return lms.REVOLUTIONS[self.resolution] * lms.MIRROR_PERIOD

    def _next_scan_start(self, t: float) -> float:
        """The mirror reaches the start angle at multiples of its period from power-up."""
        period = self._scan_duration()
        k = math.ceil((t - self.t0) / period + 1e-9)
        return self.t0 + k * period

    def _stop_stream(self) -> None:
        self.streaming = False
        self.stream_epoch += 1

    def _schedule_stream(self, t_free: float) -> None:
        """The next streamed scan: the newest one complete when the line is free."""
        epoch = self.stream_epoch
        dur = self._scan_duration()
        t_start = self._next_scan_start(t_free - dur)
        t_ready = max(t_start + dur, t_free)

        def go() -> None:
            if epoch != self.stream_epoch or not self.streaming:
                return
            end = self._send_scan(t_start, t_ready=t_ready)
            self._schedule_stream(end)

        self.port.call_at(t_ready, go)

    def _send_scan(self, t_start: float, *, t_ready: float) -> float:
        angles = self.beam_angles()
        times = self.beam_times(t_start, angles)
        true, meas, _power = self.measure(angles, t_start + self._scan_duration() / 2, times)
        self.remember(float(times.min()), angles, true, meas, float(times.max()))
        vals = np.round(meas * 1000.0) if self.units_mm else np.round(meas * 100.0)
        vals = np.where((meas > 0) & (vals < 8183), vals, self.config.no_echo).astype(np.int64)
        data = lms.scan_data([int(v) for v in vals], self.units_mm)
        tel = lms.reply(0xB0, data, self.faults.status, self.config.address)
        if self.faults.truncate_next:
            self.faults.truncate_next -= 1
            tel = tel[:len(tel) // 2]
            self.counters["truncated_scans"] += 1
        self.telegram_index += 1
        self.scans_sent += 1
        return self._send(tel, t_ready)

    # ------------------------------------------------------------------ description

    def status_block(self) -> bytes:
        """The B1 status reply's data (software version, variant, units; other bytes zero)."""
        block = bytearray(151)
        block[0:7] = SOFTWARE
        block[7] = self.mode
        struct.pack_into("<HH", block, 106, self.angle, self.resolution)
        block[121] = 1 if self.units_mm else 0
        return bytes(block)

    def status(self) -> dict:
        return {"baud": self.baud, "mode": f"0x{int(self.mode):02X}", "streaming": self.streaming,
                "variant": [self.angle, self.resolution], "units": "mm" if self.units_mm else "cm",
                "installation": self.installation, "scans_sent": self.scans_sent,
                "requests": list(self.requests[-20:]), "baud_mismatch_bytes": self.baud_mismatch,
                "counters": dict(self.counters)}


__all__ = ["LmsConfig", "LmsFaults", "SickLms200"]
