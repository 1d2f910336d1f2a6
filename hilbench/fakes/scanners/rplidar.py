"""An emulated Slamtec RPLIDAR A1 (A1M8) on a serial line: requests, motor, revolutions, nodes, capsules.

Behaviour follows the spec sheet (laser_scanners.md §1.8-1.13):

- requests are framed by bit 7 of CMD and their XOR checked (a bad one is dropped
  silently); a partial request older than 5 s is forgotten; a host at another
  baud rate than 115200 is heard as garbage;
- GET_INFO, GET_HEALTH, GET_SAMPLERATE and GET_LIDAR_CONF answer with a descriptor
  and payload in one write, a fraction of a millisecond after the request;
  every GET_LIDAR_CONF type gets an answer of the expected width (the SDK waits
  2 s per unanswered query); SET_MOTOR_PWM is accepted and ignored (A1 clients
  send it anyway); unknown commands get no answer;
- SCAN sends its descriptor at once and nodes only while the motor turns at a
  stable speed; FORCE_SCAN starts at once; EXPRESS_SCAN (working mode 0 or 1)
  streams legacy capsules (type 82) with dθ = 0; STOP ends a scan, any other
  request while scanning interrupts it first; RESET prints the boot banner and
  returns to idle (clearing a protection stop whose fault is gone);
- the motor follows DTR as on the A1 development kit's adapter (DTR cleared:
  motor runs), unless the profile says it always (or never) runs; it needs
  :attr:`RplidarConfig.spin_up` to reach a stable speed; each revolution's speed
  wanders by a few percent around 5.5 Hz;
- samples are taken every 508 µs (254 µs express) on the bench clock and each
  node leaves the UART when its sample is taken, paced at 115200 baud.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilbench.fakes.scanners.base import Scanner
from hilbench.fakes.scanners.uart import UartTx
from hilbench.fakes.scene import Pose, RangeModel, Scene
from hilbench.fakes.world import World
from hilbench.protocols import rplidar as rp
from hilbench.transports.port_state import ModemSignals

A1_SERIAL = bytes.fromhex("D8E0EDF9C7E29BD1A7E39EF24833431B")
MOTOR_POLICIES = ("dtr", "always", "off")
#: Samples generated per batch (one ray cast), about 16 ms of standard scan.
BATCH = 32
#: How long after a request a single response starts (the A1 answers within a few ms).
REPLY_LATENCY = 0.0005
#: A partial request older than this is dropped (§1.2).
REQUEST_TIMEOUT = 5.0
#: Boot after RESET: banner after this delay, requests ignored until ready.
RESET_BANNER_DELAY = 0.02
RESET_BUSY = 0.05


@dataclass
class RplidarFaults:
    """Fault knobs (spec §1.13); rates are per node/capsule, ``*_next`` counts the next ones."""

    stall: bool = False  # the motor does not turn whatever DTR says
    health_status: int = 0  # 0 good, 1 warning, 2 error (protection stop: no scan until RESET)
    health_code: int = 0
    sticky: bool = False  # the protection stop survives RESET (the fault is not gone)
    corrupt_rate: float = 0.0  # express capsule checksum wrong / node bytes flipped
    bad_flags_rate: float = 0.0  # nodes with S == S̄ or C == 0
    drop_byte_rate: float = 0.0  # one byte of a node lost (misaligns fixed-chunk readers)
    burst: bool = False  # a revolution's nodes at once instead of paced per sample
    out_of_range_angle: bool = False  # angle_q6 >= 360° on some nodes
    seed: int = 0


@dataclass
class RplidarConfig:
    """What the unit reports and how it turns."""

    model: int = 0x18
    firmware: tuple[int, int] = (1, 29)
    hardware: int = 7
    serial: bytes = A1_SERIAL
    rpm: float = 330.0  # 5.5 Hz
    sample_us: int = 508
    express_us: int = 254
    max_distance_m: float = 12.0
    typical_mode: int = 1  # Express, as the SDK's startScan(useTypicalScan) picks it
    motor: str = "dtr"
    spin_up: float = 0.5
    speed_wander: float = 0.02
    baud: int = rp.BAUD
    faults: RplidarFaults = field(default_factory=RplidarFaults)


#: Scan modes the emulator offers through GET_LIDAR_CONF: (name, µs per sample attr, answer type).
SCAN_MODES = (("Standard", "sample_us", rp.AnsType.MEASUREMENT), ("Express", "express_us",
                                                                  rp.AnsType.MEASUREMENT_CAPSULED))


class RplidarA1(Scanner):
    """The emulated A1; attach to a serial medium (``attach``) or drive ``on_bytes`` directly."""

    def __init__(self, name: str, scene: Scene | World, pose: Pose, model: RangeModel | None = None,
                 config: RplidarConfig | None = None, *, t0: float | None = None, body: str | None = None) -> None:
        super().__init__(name, scene, pose, model or RangeModel(0.15, 12.0, 0.0005, 0.005), t0=t0, body=body)
        self.config = config or RplidarConfig()
        self.faults = self.config.faults
        self.frng = np.random.default_rng(self.faults.seed + 1)
        rp.layouts()  # (made now, not on a client's first request: replies are built with them)
        self.decoder = rp.RequestDecoder()
        self.tx: UartTx | None = None
        self.state = "idle"  # idle, scanning, express, protection
        self.scan_epoch = 0
        self.dtr = True  # a host's open() asserts DTR: the dev kit's motor then stands
        self.motor_since: float | None = None  # when the motor last started
        self.last_rx = 0.0
        self.busy_until = 0.0
        self.health = (self.faults.health_status, self.faults.health_code)
        if self.health[0] == 2:
            self.state = "protection"
        self.revolutions = 0
        self.samples_sent = 0
        self._angle = 0.0
        self._freq = self.config.rpm / 60.0
        self._next_sample_t = 0.0
        self._new_rev = True
        self._rev_angles: list[np.ndarray] = []
        self._rev_true: list[np.ndarray] = []
        self._rev_meas: list[np.ndarray] = []
        self._rev_t = 0.0
        self._rev_t_last = 0.0
        self._capsule_first = True
        self._waiting_motor = False
        self._force = False
        self.baud_mismatch = 0
        if self.config.motor == "always":
            self.motor_since = self.t0 - self.config.spin_up

    # ------------------------------------------------------------------ wiring

    def attach(self, medium) -> None:
        super().attach(medium)
        self.tx = UartTx(self.port, self.config.baud, counters=self.counters)

    # ------------------------------------------------------------------ motor

    def motor_commanded(self) -> bool:
        """Whether MOTOCTL drives the motor (the policy, DTR and the stall knob)."""
        if self.faults.stall or self.config.motor == "off":
            return False
        return True if self.config.motor == "always" else not self.dtr

    def motor_stable_at(self) -> float | None:
        """When the motor reaches (or reached) a stable speed; None while it is not commanded."""
        if not self.motor_commanded() or self.motor_since is None:
            return None
        return self.motor_since + self.config.spin_up

    def on_port_event(self, event, t: float) -> None:
        """DTR from the host (``hilbench run``, RFC 2217): DTR cleared runs the motor, set stops it."""
        if not isinstance(event, ModemSignals):
            return
        self.set_dtr(event.dtr, t)

    def set_dtr(self, dtr: bool, t: float | None = None) -> None:
        """The adapter's DTR changed (True: asserted, which stops the A1's motor)."""
        t = self.now() if t is None else t
        was = self.motor_commanded()
        self.dtr = bool(dtr)
        now = self.motor_commanded()
        if now and not was:
            self.motor_since = t
            if self._waiting_motor:
                self._schedule_batch(max(t + self.config.spin_up, t))
        elif was and not now:
            self.motor_since = None

    @property
    def motor_running(self) -> bool:
        stable = self.motor_stable_at()
        return stable is not None and self.now() >= stable

    # ------------------------------------------------------------------ host bytes

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        if baud is not None and baud != self.config.baud:
            self.baud_mismatch += len(data)
            return  # framing garbage at the device's UART
        if t - self.last_rx > REQUEST_TIMEOUT:
            self.decoder.reset()
        self.last_rx = t
        for item in self.decoder.feed(data):
            if isinstance(item, rp.Request):
                self.note_request(item.name)
                self.handle(item, t)
            else:
                self.counters[f"rx_{item.kind}"] += 1

    # ------------------------------------------------------------------ requests

    def _reply(self, data: bytes, t: float) -> None:
        if self.tx is not None:
            self.tx.send(data, t + REPLY_LATENCY)

    def handle(self, req: rp.Request, t: float) -> None:
        """Act on one request received at ``t``."""
        cmd = req.cmd
        if t < self.busy_until:
            self.counters["ignored_while_booting"] += 1
            return
        if cmd == rp.Cmd.STOP:
            if self.state in ("scanning", "express"):
                self._stop_scan(t)
            return
        if cmd == rp.Cmd.SET_MOTOR_PWM:
            return  # A2/A3 accessory boards only; the A1 ignores it
        if self.state in ("scanning", "express") and cmd not in (rp.Cmd.SCAN, rp.Cmd.FORCE_SCAN,
                                                                 rp.Cmd.EXPRESS_SCAN):
            self._stop_scan(t)
        if cmd == rp.Cmd.RESET:
            self._reset(t)
        elif cmd in (rp.Cmd.SCAN, rp.Cmd.FORCE_SCAN):
            if self.state == "protection":
                return
            if self.state in ("scanning", "express"):
                self._stop_scan(t)
            self._reply(rp.descriptor(rp.NODE_SIZE, rp.MULTIPLE, rp.AnsType.MEASUREMENT), t)
            self._start_scan(t, express=False, force=cmd == rp.Cmd.FORCE_SCAN)
        elif cmd == rp.Cmd.EXPRESS_SCAN:
            if self.state == "protection" or len(req.payload) != 5:
                return
            mode = req.payload[0]
            if mode not in (0, 1):
                self.counters["express_mode_unsupported"] += 1
                return
            if self.state in ("scanning", "express"):
                self._stop_scan(t)
            self._reply(rp.descriptor(rp.CAPSULE_SIZE, rp.MULTIPLE, rp.AnsType.MEASUREMENT_CAPSULED), t)
            self._start_scan(t, express=True, force=False)
        elif cmd == rp.Cmd.GET_INFO:
            c = self.config
            self._reply(rp.descriptor(20, rp.SINGLE, rp.AnsType.DEVINFO)
                        + rp.info_payload(c.model, c.firmware, c.hardware, c.serial), t)
        elif cmd == rp.Cmd.GET_HEALTH:
            self._reply(rp.descriptor(3, rp.SINGLE, rp.AnsType.DEVHEALTH) + rp.health_payload(*self.health), t)
        elif cmd == rp.Cmd.GET_SAMPLERATE:
            self._reply(rp.descriptor(4, rp.SINGLE, rp.AnsType.SAMPLERATE)
                        + rp.samplerate_payload(self.config.sample_us, self.config.express_us), t)
        elif cmd == rp.Cmd.GET_LIDAR_CONF:
            if len(req.payload) >= 4:
                value = self.lidar_conf(req.payload)
                self._reply(rp.descriptor(len(value), rp.SINGLE, rp.AnsType.GET_LIDAR_CONF) + value, t)
        else:
            self.counters["unknown_command"] += 1

    def lidar_conf(self, payload: bytes) -> bytes:
        """The answer (type echo + value) to a GET_LIDAR_CONF payload (§1.5.4)."""
        import struct

        conf = struct.unpack_from("<I", payload)[0]
        # pyrplidar: u32 type + u16 mode; the SDK: u32 type + 32 reserved bytes + u16 mode.
        mode = struct.unpack_from("<H", payload, len(payload) - 2)[0] if len(payload) in (6, 38) else 0
        c = self.config
        known = mode < len(SCAN_MODES)
        name, us_attr, ans = SCAN_MODES[mode if known else 0]
        if conf == rp.Conf.SCAN_MODE_COUNT:
            value = struct.pack("<H", len(SCAN_MODES))
        elif conf == rp.Conf.SCAN_MODE_US_PER_SAMPLE:
            value = struct.pack("<I", int(getattr(c, us_attr) * 256))
        elif conf == rp.Conf.SCAN_MODE_MAX_DISTANCE:
            value = struct.pack("<I", int(c.max_distance_m * 256))
        elif conf == rp.Conf.SCAN_MODE_ANS_TYPE:
            value = struct.pack("<B", int(ans))
        elif conf == rp.Conf.SCAN_MODE_TYPICAL:
            value = struct.pack("<H", c.typical_mode)
        elif conf == rp.Conf.SCAN_MODE_NAME:
            value = name.encode("ascii") + b"\0"
        elif conf == rp.Conf.DESIRED_ROT_FREQ:
            value = rp.DesiredRotFreq.build({"rpm": int(c.rpm), "pwm_ref": 660})
        else:
            value = struct.pack("<I", 0)  # an answer of some width: the SDK must not wait 2 s for it
        return rp.conf_answer(conf, value)

    def _reset(self, t: float) -> None:
        c = self.config
        if self.state == "protection" and not self.faults.sticky:
            self.health = (0, 0)
            self.faults.health_status, self.faults.health_code = 0, 0
        self.state = "protection" if self.health[0] == 2 else "idle"
        self.decoder.reset()
        self.busy_until = t + RESET_BUSY
        banner = (f"RP LIDAR System.\r\nFirmware Ver {c.firmware[0]}.{c.firmware[1]:02d} - rtm, "
                  f"HW Ver {c.hardware}\r\nModel: {c.model:02X}\r\n").encode("ascii")
        if self.tx is not None:
            self.tx.send(banner, t + RESET_BANNER_DELAY)

    # ------------------------------------------------------------------ scanning

    def _start_scan(self, t: float, *, express: bool, force: bool) -> None:
        self.state = "express" if express else "scanning"
        self._force = force
        self.scan_epoch += 1
        self._new_rev = True
        self._capsule_first = True
        self._rev_angles, self._rev_true, self._rev_meas = [], [], []
        self._angle = float(self.frng.uniform(0.0, 360.0))  # a random phase, as a real unit's
        self._draw_speed()
        start = t + 0.001
        if force and self.motor_stable_at() is None:
            self._freq = 0.0
        if not force:
            stable = self.motor_stable_at()
            if stable is None:
                self._waiting_motor = True  # descriptor, then silence until the motor turns
                return
            start = max(start, stable)
        self._waiting_motor = False
        self._schedule_batch(start)

    def _stop_scan(self, t: float) -> None:
        self.state = "idle" if self.state != "protection" else "protection"
        self.scan_epoch += 1
        self._waiting_motor = False
        if self.tx is not None:
            self.tx.cancel(t)

    def _draw_speed(self) -> None:
        w = self.config.speed_wander
        f = self.config.rpm / 60.0
        self._freq = f * float(np.clip(1.0 + w * self.frng.standard_normal(), 1 - 3 * w, 1 + 3 * w)) if w else f

    def _schedule_batch(self, t: float) -> None:
        if self.port is None:
            return
        self._waiting_motor = False
        self._next_sample_t = t
        epoch = self.scan_epoch
        self.port.call_at(t, lambda: self._batch(epoch))

    def _batch(self, epoch: int) -> None:
        if epoch != self.scan_epoch or self.state not in ("scanning", "express"):
            return
        express = self.state == "express"
        ts = (self.config.express_us if express else self.config.sample_us) * 1e-6
        t0 = self._next_sample_t
        stable = self.motor_stable_at()
        turning = stable is not None and stable <= t0
        if self._force and not turning:
            self._freq = 0.0  # FORCE_SCAN does not check the rotation: samples at a standing angle
        elif stable is None or stable > t0:
            # The motor stopped (or slowed): nodes stop until it turns again at a stable speed.
            self._waiting_motor = True
            self._new_rev = True
            if stable is not None:
                self._schedule_batch(stable)
            return
        n = BATCH
        times = t0 + ts * np.arange(n)
        step = 360.0 * self._freq * ts
        angles = self._angle + step * np.arange(n)
        starts = np.zeros(n, bool)
        if self._new_rev:
            starts[0] = True
            self._new_rev = False
        wraps = np.nonzero(angles >= 360.0)[0]
        if len(wraps):
            k = int(wraps[0])
            starts[k] = True
            angles[k:] -= 360.0
            if self._freq:
                self._draw_speed()  # a new revolution, a slightly different speed
        self._angle = float(angles[-1] + step)  # >= 360: the next batch's first sample starts a revolution
        rng_true, meas, power = self.measure(angles, float(times[n // 2]), times)
        self._record(angles, rng_true, meas, starts, times)
        if express:
            self._send_capsule(angles, meas, float(times[-1]))
        else:
            self._send_nodes(angles, meas, power, starts, times)
        self._next_sample_t = float(t0 + ts * n)
        self._schedule_next(epoch)

    def _schedule_next(self, epoch: int) -> None:
        # Generate a batch shortly before its first sample is due: nodes stay paced by their own times.
        self.port.call_at(self._next_sample_t - 0.002, lambda: self._batch(epoch))

    def _record(self, angles, rng_true, meas, starts, times) -> None:
        """Keep each finished revolution with its true ranges (:attr:`truth`)."""
        cuts = [k for k in range(len(angles)) if starts[k]]
        bounds = [0, *cuts, len(angles)]
        for a, b in zip(bounds[:-1], bounds[1:], strict=False):
            if a == b:
                continue
            if starts[a]:
                if self._rev_angles:
                    self.remember(self._rev_t, np.concatenate(self._rev_angles), np.concatenate(self._rev_true),
                                  np.concatenate(self._rev_meas), self._rev_t_last)
                    self.revolutions += 1
                self._rev_angles, self._rev_true, self._rev_meas = [], [], []
                self._rev_t = float(times[a])
            self._rev_t_last = float(times[b - 1])
            self._rev_angles.append(angles[a:b])
            self._rev_true.append(rng_true[a:b])
            self._rev_meas.append(meas[a:b])

    def _send_nodes(self, angles, meas, power, starts, times) -> None:
        f = self.faults
        dist_q2 = np.round(meas * 4000.0).astype(np.int64)
        dist_q2 = np.clip(dist_q2, 0, 0xFFFF)
        quality = np.where(dist_q2 > 0, np.clip(np.round(10 + 53 * np.sqrt(power * 4)), 1, 63), 0).astype(np.int64)
        angle_q6 = np.round(angles * 64.0).astype(np.int64) % (360 * 64)
        if f.out_of_range_angle:
            angle_q6 = np.where(self.frng.random(len(angle_q6)) < 0.05, 360 * 64 + 100, angle_q6)
        raw = rp.encode_nodes(quality, angle_q6, dist_q2, starts)
        nodes = [raw[5 * k:5 * k + 5] for k in range(len(angles))]
        if f.bad_flags_rate or f.drop_byte_rate or f.corrupt_rate:
            nodes = [self._node_faults(nd) for nd in nodes]
        tx = self.tx
        if f.burst:
            # Everything measured so far in one write at the batch's end (a bursty emulator's timing).
            tx.send(b"".join(nodes), float(times[-1]))
        else:
            for nd, t in zip(nodes, times, strict=False):
                tx.send(nd, float(t))
        self.samples_sent += len(nodes)

    def _node_faults(self, nd: bytes) -> bytes:
        f, r = self.faults, self.frng
        b = bytearray(nd)
        if f.bad_flags_rate and r.random() < f.bad_flags_rate:
            if r.random() < 0.5:
                b[0] = (b[0] & 0xFC) | 0x03  # S == S̄
            else:
                b[1] &= 0xFE  # C = 0
            self.counters["bad_flag_nodes"] += 1
        if f.corrupt_rate and r.random() < f.corrupt_rate:
            b[3] ^= 0x55
            self.counters["corrupted_nodes"] += 1
        if f.drop_byte_rate and r.random() < f.drop_byte_rate:
            del b[int(r.integers(0, len(b)))]
            self.counters["dropped_bytes"] += 1
        return bytes(b)

    def _send_capsule(self, angles, meas, t_ready: float) -> None:
        dist = np.clip(np.round(meas * 1000.0), 0, 0x3FFF).astype(np.int64)
        start_q6 = int(round(angles[0] * 64.0)) % (360 * 64)
        cap = rp.capsule(start_q6, dist, self._capsule_first)
        self._capsule_first = False
        if self.faults.corrupt_rate and self.frng.random() < self.faults.corrupt_rate:
            cap = cap[:10] + bytes([cap[10] ^ 0x5A]) + cap[11:]
            self.counters["corrupted_capsules"] += 1
        self.tx.send(cap, t_ready)
        self.samples_sent += len(angles)

    # ------------------------------------------------------------------ geometry and status

    def directions(self, sensor_deg: np.ndarray, heading: np.ndarray | float) -> np.ndarray:
        """RPLIDAR angles grow clockwise seen from above, 0° straight ahead."""
        return heading - np.radians(np.asarray(sensor_deg, float))

    def set_health(self, status: int, code: int = 0) -> None:
        """Inject a health state; status 2 is a protection stop (the scan ends, no new one until RESET)."""
        self.health = (int(status), int(code))
        self.faults.health_status, self.faults.health_code = self.health
        if status == 2:
            if self.state in ("scanning", "express"):
                self._stop_scan(self.now())
            self.state = "protection"

    def status(self) -> dict:
        """What the unit is doing, for the control channel and tests."""
        return {
            "state": self.state,
            "motor": {"policy": self.config.motor, "dtr": self.dtr, "commanded": self.motor_commanded(),
                      "running": self.motor_running, "stall": self.faults.stall},
            "health": {"status": self.health[0], "error_code": self.health[1]},
            "revolutions": self.revolutions,
            "samples_sent": self.samples_sent,
            "rpm": self._freq * 60.0,
            "requests": list(self.requests[-20:]),
            "baud_mismatch_bytes": self.baud_mismatch,
            "counters": dict(self.counters),
        }


__all__ = ["A1_SERIAL", "MOTOR_POLICIES", "RplidarA1", "RplidarConfig", "RplidarFaults", "SCAN_MODES"]
