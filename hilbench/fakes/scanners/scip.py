"""An emulated Hokuyo scanner speaking SCIP 2.0 (UST-10LX over TCP, URG-04LX on a pty).

Behaviour (spec sheet laser_scanners.md §3): every request line is echoed
with its status and sum; VV, PP, II, %ST, BM, QT, RS, RT, RB (twice), TM0/1/2,
SS (0F on Ethernet models), GD/GS/GE one scan, MD/MS/ME continuous scans with
the remaining count in each echo; an unknown command gets 0E. Scans happen
every 60000/rpm ms on the unit's clock whether anyone asks or not; a GD is
answered with the next whole scan, MD sends one reply per scan (skipping K),
each reply written whole with one send. Timestamps come from a 24-bit
millisecond clock with a configurable start offset (wrap-around tests).

A real unit answers one request after another, and while its output waits
(TCP holds it back from a client that does not read) it reads no more
requests. The emulated one reads every request at once and computes each
answer when it comes, so it keeps at most :data:`MAX_WAITING` replies waiting
to go out: a request beyond is dropped unanswered and counted
(``requests_dropped`` in ``scanner_status``). A client reading its replies
never meets the bound; one pipelining 15 000 ``GD`` unread held 50 MB of
scans before.

Over TCP the unit holds one client (the host port turns others away), and
each connection starts afresh: a request line the last client began but did
not end is forgotten, a first ``RB`` it sent no longer arms a reboot, and
the continuous scans it asked for stop when it leaves, so a new client never
hears an answer to another client's bytes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hilbench.fakes.scanners.base import Scanner
from hilbench.fakes.scanners.uart import UartTx
from hilbench.fakes.scene import Pose, RangeModel, Scene
from hilbench.fakes.world import World
from hilbench.protocols import scip

#: Command processing time before a reply.
REPLY_DELAY = 0.0005
#: Replies waiting to go out (a scan's waits for the scan) beyond which a request is dropped unanswered.
MAX_WAITING = 32


@dataclass(frozen=True)
class ScipModel:
    """A unit's identity and geometry (PP/VV values)."""

    name: str
    dmin: int
    dmax: int
    ares: int
    amin: int
    amax: int
    afrt: int
    rpm: int
    vendor: str
    product: str
    firmware: str
    serial: str
    ethernet: bool
    intensity: bool
    sigma0: float  # range noise (m)

    @property
    def period(self) -> float:
        return 60.0 / self.rpm


MODELS = {
    "ust-10lx": ScipModel("UST-10LX", 20, 30000, 1440, 0, 1080, 540, 2400, "Hokuyo Automatic Co.,Ltd.",
                          "SOKUIKI Sensor UST-10LX", "1.04.00", "H1320012", True, True, 0.01),
    "urg-04lx": ScipModel("URG-04LX", 20, 5600, 1024, 44, 725, 384, 600, "Hokuyo Automatic Co.,Ltd.",
                          "SOKUIKI Sensor URG-04LX", "3.1.00(18/Jan./2007)", "H0614967", False, False, 0.01),
}
#: Value reported for a step without a return (an error code below DMIN).
NO_ECHO = 1


@dataclass
class ScipFaults:
    """Fault knobs (spec §3.9)."""

    bad_sum_next: int = 0  # corrupt the sum of a data line in the next N scan replies
    truncate_next: int = 0  # cut the last data line of the next N scan replies short
    unstable_next: int = 0  # answer the next N MD scans with status 0M (no data)
    burst: bool = False  # coalesce continuous replies in pairs (breaks clients that read one reply per recv)
    seed: int = 0


@dataclass
class ScipConfig:
    clock_offset_ms: int = 0
    faults: ScipFaults = field(default_factory=ScipFaults)


class ScipScanner(Scanner):
    """The emulated SCIP 2.0 unit."""

    def __init__(self, name: str, scene: Scene | World, pose: Pose, model: RangeModel | None, unit: ScipModel,
                 config: ScipConfig | None = None, *, t0: float | None = None,
                 connected=None, session=None, body: str | None = None) -> None:
        super().__init__(name, scene, pose,
                         model or RangeModel(unit.dmin / 1000, unit.dmax / 1000, unit.sigma0, 0.0), t0=t0, body=body)
        self.unit = unit
        self.config = config or ScipConfig()
        self.faults = self.config.faults
        self.decoder = scip.RequestDecoder()
        scip.layouts()  # (made now, not on a client's first request: it parses GD/MD parameters with them)
        self.tx: UartTx | None = None
        self.laser = False
        self.timesync = False
        self.sleeping = False
        self.reboot_armed = False
        self.md: dict | None = None  # continuous measurement in progress
        self.md_epoch = 0
        self.scans_sent = 0
        self.connected = connected or (lambda: True)
        # Which connection the host port serves (a TCP port counts them; None on a pty, which has no sessions).
        self.session = session or (lambda: None)
        self._session = self.session()
        self._held: bytes = b""

    def attach(self, medium) -> None:
        super().attach(medium)
        self.tx = UartTx(self.port, None)  # USB CDC-ACM or TCP: each reply goes out whole

    # ------------------------------------------------------------------ clock and geometry

    def clock_ms(self, t: float) -> int:
        """The unit's 24-bit millisecond clock at monotonic time ``t``."""
        return (int((t - self.t0) * 1000.0) + self.config.clock_offset_ms) % scip.TIMESTAMP_WRAP

    def directions(self, sensor_deg: np.ndarray, heading: np.ndarray | float) -> np.ndarray:
        """Steps grow counter-clockwise; the front step AFRT looks straight ahead."""
        return heading + np.radians(np.asarray(sensor_deg, float))

    def step_angles(self, start: int, end: int) -> np.ndarray:
        steps = np.arange(start, end + 1)
        return (steps - self.unit.afrt) * 360.0 / self.unit.ares

    def next_scan_start(self, t: float) -> float:
        period = self.unit.period
        return self.t0 + math.ceil((t - self.t0) / period + 1e-9) * period

    # ------------------------------------------------------------------ host bytes

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        session = self.session()
        if session != self._session:  # the first bytes of a new connection (the medium keeps their order)
            self._session = session
            self.decoder.reset()
            self.reboot_armed = False
            if self.md is not None and self.md.get("session") != session:
                self._stop_md()
        for item in self.decoder.feed(data):
            if isinstance(item, scip.Request):
                self.note_request(item.cmd)
                if self.tx is not None and self.tx.waiting >= MAX_WAITING:
                    self.counters["requests_dropped"] += 1  # (see the module docstring)
                    continue
                self.handle(item, t)
            else:
                self.counters[f"rx_{item.kind}"] += 1

    def _send(self, data: bytes, t: float) -> float:
        if self.tx is None:
            return t
        return self.tx.send(data, t, whole=True)

    def _answer(self, req: scip.Request, status: str, body: bytes = b"", t: float | None = None) -> None:
        t = self.now() if t is None else t
        self._send(scip.reply(req.line, status, body), t + REPLY_DELAY)

    # ------------------------------------------------------------------ commands

    def handle(self, req: scip.Request, t: float) -> None:
        """Answer one request line received at ``t``."""
        u = self.unit
        cmd = req.cmd
        if len(req.string) > 16:
            return self._answer(req, "0G", t=t)
        if cmd == "VV":
            body = (scip.info_line("VEND", u.vendor) + scip.info_line("PROD", u.product)
                    + scip.info_line("FIRM", u.firmware) + scip.info_line("PROT", "SCIP 2.0")
                    + scip.info_line("SERI", u.serial))
            return self._answer(req, "00", body, t)
        if cmd == "PP":
            body = b"".join(scip.info_line(k, str(v)) for k, v in (
                ("MODL", u.name), ("DMIN", u.dmin), ("DMAX", u.dmax), ("ARES", u.ares), ("AMIN", u.amin),
                ("AMAX", u.amax), ("AFRT", u.afrt), ("SCAN", u.rpm)))
            return self._answer(req, "00", body, t)
        if cmd == "II":
            body = b"".join(scip.info_line(k, v) for k, v in (
                ("MODL", u.name), ("LASR", "ON" if self.laser else "OFF"), ("SCSP", f"Initial {u.rpm}[rpm]"),
                ("MESM", "Measuring by Normal Mode"), ("SBPS", "Ethernet 100 [Mbps]" if u.ethernet else
                                                     "USB only"),
                ("TIME", f"{self.clock_ms(t):06X}"), ("STAT", "Stable 000 no error.")))
            return self._answer(req, "00", body, t)
        if cmd == "%ST":
            state = "005" if self.sleeping else "002" if self.timesync else "004" if self.md else \
                "003" if self.laser else "000"
            return self._answer(req, "00", scip.data_lines(state.encode()), t)
        if cmd == "%SL":
            self._stop_md()
            self.laser, self.sleeping = False, True
            return self._answer(req, "00", t=t)
        if cmd == "BM":
            if self.timesync:
                return self._answer(req, "01", t=t)  # cannot light in time-sync mode
            self.sleeping = False
            if self.md is not None or self.laser:
                return self._answer(req, "02", t=t)
            self.laser = True
            return self._answer(req, "00", t=t)
        if cmd == "QT":
            self._stop_md()
            self.laser = False
            self.timesync = False
            return self._answer(req, "00", t=t)
        if cmd in ("RS", "RT"):
            self._stop_md()
            self.laser = self.timesync = self.sleeping = False
            return self._answer(req, "00", t=t)
        if cmd == "RB":
            if self.reboot_armed:
                self.reboot_armed = False
                self._stop_md()
                self.laser = self.timesync = False
                return self._answer(req, "00", t=t)
            self.reboot_armed = True
            return self._answer(req, "01", t=t)
        if cmd == "TM":
            return self._tm(req, t)
        if cmd == "SS":
            return self._answer(req, "0F" if u.ethernet else "00", t=t)
        if cmd in ("GD", "GS", "GE"):
            return self._single(req, t)
        if cmd in ("MD", "MS", "ME"):
            return self._continuous(req, t)
        if cmd == "SC" and req.params.startswith("IP2.0"):
            return self._answer(req, "0E", t=t)  # already speaking SCIP 2.0
        return self._answer(req, "0E", t=t)

    def _tm(self, req: scip.Request, t: float) -> None:
        code = req.params
        if code == "0":
            if self.timesync:
                return self._answer(req, "02", t=t)
            self._stop_md()
            self.laser = False
            self.timesync = True
            return self._answer(req, "00", t=t)
        if code == "1":
            if not self.timesync:
                return self._answer(req, "04", t=t)
            return self._answer(req, "00", scip.timestamp_line(self.clock_ms(t + REPLY_DELAY)), t)
        if code == "2":
            if not self.timesync:
                return self._answer(req, "03", t=t)
            self.timesync = False
            return self._answer(req, "00", t=t)
        return self._answer(req, "01", t=t)

    def _check_range(self, req: scip.Request) -> tuple[str | None, dict | None]:
        f = req.fields()
        if f is None:
            return ("0H" if len(req.params) < 10 else "0D" if len(req.params) > 13 else "01"), None
        u = self.unit
        if not u.amin <= f["start"] <= u.amax:
            return "01", None
        if not f["start"] <= f["end"] <= u.amax:
            return "02", None
        if f["cluster"] > 99:
            return "03", None
        if req.cmd in ("GE", "ME") and not u.intensity:
            return "0E", None
        return None, f

    def _single(self, req: scip.Request, t: float) -> None:
        err, f = self._check_range(req)
        if err:
            return self._answer(req, err, t=t)
        if self.timesync or not self.laser:
            return self._answer(req, "10", t=t)
        t_start = self.next_scan_start(t)
        body = self._scan_body(req.cmd, f, t_start)
        self._send(scip.reply(req.line, "00", body), t_start + self.unit.period)

    def _continuous(self, req: scip.Request, t: float) -> None:
        err, f = self._check_range(req)
        if err:
            return self._answer(req, err, t=t)
        if self.timesync:
            return self._answer(req, "10", t=t)
        self._stop_md()
        self.laser = True
        self.sleeping = False
        self.md = {"req": req, "fields": f, "remaining": f["scans"], "skip": f["skip"], "session": self._session}
        self.md_epoch += 1
        self._answer(req, "00", t=t)
        epoch = self.md_epoch
        first = self.next_scan_start(t + 0.002)  # a short gap after the acknowledgement
        self.port.call_at(first + self.unit.period, lambda: self._md_scan(epoch, first))

    def _stop_md(self) -> None:
        self.md = None
        self.md_epoch += 1
        self._held = b""

    def _md_scan(self, epoch: int, t_start: float) -> None:
        md = self.md
        if epoch != self.md_epoch or md is None:
            return
        if not self.connected() or md.get("session") != self.session():
            self._stop_md()  # the client left (another may have come): the unit stops streaming
            return
        req, f = md["req"], md["fields"]
        p = req.params
        endless = f["scans"] == 0
        if not endless:
            md["remaining"] -= 1
        remaining = 0 if endless else md["remaining"]
        echo = f"{req.cmd}{p[:-2]}{remaining:02d}{';' + req.string if req.string else ''}".encode("ascii")
        t_ready = t_start + self.unit.period
        if self.faults.unstable_next:
            self.faults.unstable_next -= 1
            out = scip.reply(echo, "0M")
        else:
            out = scip.reply(echo, "99", self._scan_body(req.cmd, f, t_start))
        if self.faults.burst and not self._held:
            self._held = out
        else:
            self._send(self._held + out, t_ready)
            self._held = b""
        if not endless and md["remaining"] <= 0:
            if self._held:
                self._send(self._held, t_ready)
            self.md = None
            return
        nxt = t_start + self.unit.period * (1 + md["skip"])
        self.port.call_at(nxt + self.unit.period, lambda: self._md_scan(epoch, nxt))

    def _scan_body(self, cmd: str, f: dict, t_start: float) -> bytes:
        start, end, cluster = f["start"], f["end"], max(1, f["cluster"])
        angles = self.step_angles(start, end)
        # The mirror passes one step every period / ARES: beam k of the range is taken k steps after the first.
        times = t_start + np.arange(len(angles)) * self.unit.period / self.unit.ares
        true, meas, power = self.measure(angles, t_start + self.unit.period / 2, times)
        self.remember(t_start, angles, true, meas, float(times[-1]))
        mm = np.where(meas > 0, np.round(meas * 1000.0), NO_ECHO).astype(np.int64)
        if cluster > 1:  # a cluster reports its smallest valid distance
            n = len(mm) // cluster * cluster
            grp = mm[:n].reshape(-1, cluster)
            valid = np.where(grp >= self.unit.dmin, grp, np.iinfo(np.int64).max)
            mm = np.where(valid.min(axis=1) < np.iinfo(np.int64).max, valid.min(axis=1), NO_ECHO)
            power = power[:n].reshape(-1, cluster).max(axis=1)
        chars = scip.ENCODING[cmd]
        if chars == 2:
            mm = np.minimum(mm, 4095)
        if cmd in scip.WITH_INTENSITY:
            inten = np.clip(np.round(power * 12000), 0, 262143).astype(np.int64)
            vals = np.stack([mm, inten], axis=1).reshape(-1)
        else:
            vals = mm
        payload = scip.encode_values(vals, chars)
        lines = scip.data_lines(payload)
        if self.faults.bad_sum_next:
            self.faults.bad_sum_next -= 1
            k = lines.index(b"\n") - 1
            lines = lines[:k] + bytes([((lines[k] - 0x30 + 1) & 0x3F) + 0x30]) + lines[k + 1:]
            self.counters["bad_sums_sent"] += 1
        if self.faults.truncate_next:
            self.faults.truncate_next -= 1
            last = lines.rstrip(b"\n").rfind(b"\n") + 1
            lines = lines[:last] + lines[last:last + 10] + b"\n"
            self.counters["truncated_sent"] += 1
        self.scans_sent += 1
        return scip.timestamp_line(self.clock_ms(t_start)) + lines

    def status(self) -> dict:
        return {"model": self.unit.name, "laser": self.laser, "timesync": self.timesync,
                "continuous": None if self.md is None else {"cmd": self.md["req"].cmd,
                                                            "remaining": self.md["remaining"]},
                "clock_ms": self.clock_ms(self.now()), "scans_sent": self.scans_sent,
                "requests": list(self.requests[-20:]), "counters": dict(self.counters)}


__all__ = ["MAX_WAITING", "MODELS", "NO_ECHO", "ScipConfig", "ScipFaults", "ScipModel", "ScipScanner"]
