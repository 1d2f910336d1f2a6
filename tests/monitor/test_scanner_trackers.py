"""Scanner trackers and instruments with bytes alone: scans, rates, health, checksum failures, sniffing, views."""

from __future__ import annotations

import numpy as np

from hilbench import registry
from hilbench.dashboard import Dashboard
from hilbench.monitor.scanners.rplidar_tracker import RplidarTracker
from hilbench.monitor.scanners.scip2_tracker import ScipTracker
from hilbench.monitor.scanners.sick_lms200_tracker import SickTracker
from hilbench.protocols import rplidar as rp
from hilbench.protocols import scip
from hilbench.protocols import sick_lms200 as lms


def _revolutions(n: int, per_rev: int = 360) -> bytes:
    out = bytearray(rp.descriptor(5, 1, 0x81))
    for _ in range(n):
        for k in range(per_rev):
            out += rp.node(40, k * 64, 4000, k == 0)
    return bytes(out)


def test_rplidar_tracker_counts_revolutions_and_health():
    tr = RplidarTracker()
    tr.feed(0.0, "app", rp.request(rp.Cmd.GET_HEALTH))
    tr.feed(0.001, "device", rp.descriptor(3, 0, 6) + rp.health_payload(1, 0x0101))
    data = _revolutions(4)
    step = len(data) // 8
    for k in range(9):
        tr.feed(0.01 + k * 0.09, "device", data[k * step:(k + 1) * step])
    assert tr.requests == 1 and tr.health.startswith("warning")
    assert tr.scans == 3 and tr.last_scan.points == 360
    assert np.allclose(tr.last_scan.ranges, 1.0)
    bad = bytearray(rp.request(rp.Cmd.EXPRESS_SCAN, bytes(5)))
    bad[-1] ^= 1
    tr.feed(1.0, "app", bytes(bad))
    assert tr.checksum_failures == 1 and tr.error_count == 1


def test_sick_tracker_scans_and_crc_failures():
    tr = SickTracker()
    tr.feed(0.0, "lms", lms.request(lms.Cmd.SCAN, b"\x01"))
    tr.feed(0.1, "lms-device", b"\x06" + lms.reply(0xB0, lms.scan_data([2000] * 361, True)))
    bad = bytearray(lms.reply(0xB0, lms.scan_data([2000] * 361, True)))
    bad[10] ^= 0xFF
    tr.feed(0.3, "lms-device", b"\x06" + bytes(bad) + b"\x15")
    assert tr.requests == 1 and tr.scans == 1 and tr.last_scan.points == 361
    assert tr.checksum_failures == 1
    assert np.isclose(tr.last_scan.angles[0], -np.pi / 2) and np.isclose(tr.last_scan.angles[-1], np.pi / 2)


def test_scip_tracker_uses_the_units_parameters():
    tr = ScipTracker()
    tr.feed(0.0, "app", b"PP\n")
    pp = b"".join(scip.info_line(k, str(v)) for k, v in (("MODL", "URG-04LX"), ("DMIN", 20), ("DMAX", 5600),
                                                            ("ARES", 1024), ("AMIN", 44), ("AMAX", 725),
                                                            ("AFRT", 384), ("SCAN", 600)))
    tr.feed(0.01, "device", scip.reply(b"PP", "00", pp))
    body = scip.timestamp_line(1000) + scip.data_lines(scip.encode_values([1500] * 682, 3))
    for k in range(3):
        tr.feed(0.1 * (k + 1), "device", scip.reply(b"MD0044072500001", "99", body))
    assert tr.scans == 3 and abs(tr.scan_rate - 10.0) < 1e-6 and tr.points_per_scan == 682
    assert np.isclose(tr.last_scan.angles[384 - 44], 0.0)
    broken = scip.reply(b"GD0044004601", "00", scip.timestamp_line(5) + b"0?X0GL0O@:\n")
    tr.feed(1.0, "device", broken)
    assert tr.checksum_failures == 1


def test_instruments_are_registered_and_sniff_their_traffic():
    for name in ("rplidar", "sick-lms200", "scip2"):
        assert registry.instrument_for(name) is not None
    assert registry.instrument_for("sick").protocol == "sick-lms200"
    assert registry.instrument_for("scip").protocol == "scip2"
    samples = {
        "rplidar": _revolutions(1),
        "sick-lms200": b"\x06" + lms.reply(0xB0, lms.scan_data([1000] * 5, True)),
        "scip2": scip.reply(b"BM", "00") + scip.reply(b"VV", "00", scip.info_line("PROT", "SCIP 2.0")),
    }
    for proto, data in samples.items():
        scores = {i.protocol: i.sniff(data) for i in registry.instruments.values()}
        assert max(scores, key=scores.get) == proto, scores


def test_dashboard_views_fit_the_screen():
    tr = RplidarTracker()
    tr.feed(0.0, "device", _revolutions(3))
    inst = registry.instrument_for("rplidar")
    for view in inst.views().views:
        dash = Dashboard(tr, views=inst.views(), view=view, source="test")
        group = dash.render(80, 24)
        assert len(group.renderables) == 24
    text = "\n".join(str(t) for t in Dashboard(tr, views=inst.views(), view="scan").render(80, 24).renderables)
    assert "+" in text and "*" in text and "scans 2" in text
