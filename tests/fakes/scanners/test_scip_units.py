"""The emulated SCIP 2.0 units: the URG-04LX on a pty (byte exchanges of the sheet) and the UST's clock."""

from __future__ import annotations

import time

import numpy as np
import pytest
import serial

from hilbench.protocols import scip
from tests.fakes.scanners.conftest import fraction_within


class Urg:
    def __init__(self, path: str) -> None:
        self.port = serial.Serial(path, 115200, timeout=0.05)
        self.dec = scip.ReplyDecoder()

    def ask(self, line: bytes, n: int = 1, timeout: float = 3.0) -> list[scip.Reply]:
        self.port.write(line)
        out: list = []
        deadline = time.monotonic() + timeout
        while len(out) < n and time.monotonic() < deadline:
            out += [r for r in self.dec.feed(self.port.read(4096)) if isinstance(r, scip.Reply)]
        return out


@pytest.fixture
def urg(scanners):
    u = Urg(scanners.endpoint("urg").path)
    yield u
    u.port.close()


def test_version_parameters_and_bad_commands(urg):
    vv = urg.ask(b"VV\n")[0]
    assert vv.raw == (b"VV\n00P\nVEND:Hokuyo Automatic Co.,Ltd.;[\nPROD:SOKUIKI Sensor URG-04LX;[\n"
                      b"FIRM:3.1.00(18/Jan./2007);`\nPROT:SCIP 2.0;N\nSERI:H0614967;V\n\n")
    pp = urg.ask(b"PP\n")[0]
    assert pp.raw == (b"PP\n00P\n" + scip.info_line("MODL", "URG-04LX") + b"DMIN:20;4\nDMAX:5600;_\nARES:1024;\\\nAMIN:44;7\nAMAX:725;o\n"
                      b"AFRT:384;6\nSCAN:600;e\n\n")
    assert urg.ask(b"XX\n")[0].raw == b"XX\n0Ee\n\n"
    assert urg.ask(b"GD0044004601\n")[0].raw == b"GD0044004601\n10Q\n\n"  # laser off
    assert urg.ask(b"BM\n")[0].raw == b"BM\n00P\n\n"
    assert urg.ask(b"BM\n")[0].raw == b"BM\n02R\n\n"
    assert urg.ask(b"GD0900099901\n")[0].status == "01"  # start step beyond AMAX
    assert urg.ask(b"%ST\n")[0].raw == b"%ST\n00P\n003C\n\n"
    assert urg.ask(b"RB\n")[0].status == "01" and urg.ask(b"RB\n")[0].status == "00"


def test_single_scan_echo_string_and_truth(scanners, urg):
    urg.ask(b"BM\n")
    rep = urg.ask(b"GD0044072501;abc\r\n")[0]
    assert rep.echo == "GD0044072501;abc" and rep.status == "00" and rep.bad_sums == 0
    ts, dist, _ = rep.scan()
    assert len(dist) == 725 - 44 + 1
    angles = (np.arange(44, 726) - 384) * 2 * np.pi / 1024  # counter-clockwise from the front step
    r = np.asarray(dist) / 1000.0
    valid = r <= 5.6
    assert fraction_within(angles[valid], r[valid], sigma0=0.01, sigma_k=0.0) > 0.97
    assert fraction_within(-angles[valid], r[valid], sigma0=0.01, sigma_k=0.0) < 0.5
    truth = scanners.device("urg").truth[-1]
    assert np.array_equal(np.where(truth.measured > 0, np.round(truth.measured * 1000), 1), dist)
    two = urg.ask(b"GS0044004601\n")[0]
    assert two.status == "00" and len(two.scan()[1]) == 3 and max(two.scan()[1]) <= 4095


def test_continuous_scans_count_down(urg):
    replies = urg.ask(b"MD0300031000003\n", n=4, timeout=3)
    assert replies[0].raw == b"MD0300031000003\n00P\n\n"
    assert [r.echo for r in replies[1:]] == ["MD0300031000002", "MD0300031000001", "MD0300031000000"]
    assert all(r.status == "99" for r in replies[1:])
    stamps = [r.scan()[0] for r in replies[1:]]
    assert np.diff(stamps).tolist() == [100, 100]  # 600 rpm: 100 ms apart


def test_time_sync_modes(urg):
    assert urg.ask(b"TM1\n")[0].status == "04"
    assert urg.ask(b"TM0\n")[0].status == "00"
    assert urg.ask(b"TM0\n")[0].status == "02"
    a = urg.ask(b"TM1\n")[0]
    time.sleep(0.05)  # the unit's clock must advance with real time between two reads
    b = urg.ask(b"TM1\n")[0]
    assert 45 <= scip.decode(b.lines[0]) - scip.decode(a.lines[0]) <= 500
    assert urg.ask(b"TM2\n")[0].status == "00" and urg.ask(b"TM2\n")[0].status == "03"


def test_clock_wraps_at_24_bits(hilbench_bench, tmp_path):
    from hilbench.bench.profile import resolve

    text = resolve("scanners").read_text().replace('model = "urg-04lx"',
                                                   'model = "urg-04lx"\nclock_offset_ms = 16_777_000')
    path = tmp_path / "wrap.toml"
    path.write_text(text)
    bench = hilbench_bench(path)
    u = Urg(bench.endpoint("urg").path)
    try:
        replies = u.ask(b"MD0300031000005\n", n=6, timeout=3)
        stamps = [r.scan()[0] for r in replies[1:]]
        assert min(stamps) < 1000 < 16_700_000 < max(stamps)  # wrapped within the run
    finally:
        u.port.close()
