"""The UDP monitor's dashboard views: traffic overview, XRCE sessions, RTPS discovery, event log.

Keys: ``1``/``o`` overview (classes, flags, senders), ``2``/``x`` XRCE (sessions,
their topics and streams), ``3``/``r`` RTPS (participants, topics, endpoints),
``4``/``e`` events. Each screen is exactly the terminal's height (scrolling
with Up/Down) and uses ASCII only. Zeroed datagrams are shown in red wherever
they are counted.
"""

from __future__ import annotations

from rich.console import Group
from rich.text import Text

from hilbench.monitor.udp.flows import Rate
from hilbench.monitor.udp.tracker import UdpTracker
from hilbench.protocols import rtps as r
from hilbench.protocols import xrce_dds as x

VIEWS = ("overview", "xrce", "rtps", "events")
TITLES = {"overview": "UDP traffic", "xrce": "XRCE sessions", "rtps": "RTPS discovery", "events": "Events"}


def _line(text: str | Text, style: str = "", width: int = 80) -> Text:
    t = text if isinstance(text, Text) else Text(text, style=style)
    t.no_wrap = True
    t.truncate(width, overflow="ellipsis")
    return t


def _rate(rate: Rate | None, timed: bool) -> str:
    v = rate.rate() if rate is not None and timed else None
    return "-" if v is None else f"{v:8.2f}/s"


def _overview(tr: UdpTracker, width: int) -> list[Text]:
    out = [_line(f" {'class':<10} {'datagrams':>10} {'bytes':>12} {'rate':>11}", "bold", width)]
    for name, (n, nbytes) in tr.classes.items():
        out.append(_line(f" {name:<10} {n:>10} {nbytes:>12} {_rate(tr.rates[name], tr.timestamps):>11}", "", width))
    out.append(_line(""))
    zero = tr.flags.get("xrce.zero_fill", 0)
    out.append(_line(f" zeroed datagrams: {zero}", "bold red" if zero else "green", width))
    for name, n in sorted(tr.flags.items()):
        out.append(_line(f"   {name:<28} {n:>8}", "red" if name.startswith("xrce.zero") else "yellow", width))
    out.append(_line(""))
    out.append(_line(f" {'sender':<24} {'datagrams':>10} {'bytes':>12}", "bold", width))
    for src, (n, nbytes) in sorted(tr.senders.items(), key=lambda kv: -kv[1][0]):
        out.append(_line(f" {src:<24} {n:>10} {nbytes:>12}", "", width))
    return out


def _xrce(tr: UdpTracker, width: int) -> list[Text]:
    out: list[Text] = []
    if not tr.xrce.sessions:
        return [_line(" no XRCE traffic yet", "dim", width)]
    for s in tr.xrce.sessions.values():
        style = {"established": "green", "torn down": "bold red", "rejected": "red", "closed": "dim"}.get(s.state, "")
        key = s.key.hex().upper() if s.key else "-"
        sid = f"0x{s.session_id:02X}" if s.session_id is not None else "-"
        flags = " ".join(f"{k.split('.', 1)[1]}={v}" for k, v in s.flags.items())
        out.append(_line(f" {s.client} -> {s.agent}  key {key} session {sid}  [{s.state}]  {flags}", style, width))
        for (direction, oid), rate in s.samples.items():
            topic, type_name = s.topic_of(oid)
            out.append(_line(f"   {direction} {x.object_text(oid):<22} {str(topic):<24} {rate.count:>7} "
                             f"{_rate(rate, tr.timestamps)}", "", width))
        for (direction, sid_), st in sorted(s.streams.items()):
            win = s.windows.get((direction, sid_))
            out.append(_line(f"   {direction} stream 0x{sid_:02X} rx {st.received} lost {st.lost} dup {st.duplicates} "
                             f"retx {st.retransmissions}" + (f" window {win}" if win is not None else ""), "dim",
                             width))
    return out


def _rtps(tr: UdpTracker, width: int) -> list[Text]:
    st = tr.rtps
    if not st.participants:
        return [_line(" no RTPS traffic yet", "dim", width)]
    out = [_line(f" {'participant':<28} {'vendor':<20} {'SPDP':>6} {'rate':>11}", "bold", width)]
    for p in st.participants.values():
        out.append(_line(f" {r.guid_text(p.prefix):<28} {r.VENDOR_NAMES.get(p.vendor, p.vendor.hex()):<20} "
                         f"{p.spdp.count:>6} {_rate(p.spdp, tr.timestamps):>11}", "", width))
    out.append(_line(""))
    out.append(_line(f" {'topic':<28} {'type':<34} {'W':>2} {'R':>2} {'samples':>8} {'lost':>6} {'rate':>9}", "bold",
                     width))
    for t in st.topics().values():
        rate = f"{t['rate_hz']:.2f}/s" if t["rate_hz"] else "-"
        out.append(_line(f" {t['topic']:<28} {t['type']:<34} {len(t['writers']):>2} {len(t['readers']):>2} "
                         f"{t['samples']:>8} {t['lost']:>6} {rate:>9}", "", width))
    return out


def _events(tr: UdpTracker, width: int) -> list[Text]:
    out = []
    for t, kind, text in reversed(tr.events):
        when = f"{t - (tr.t0 or 0):10.3f}" if tr.timestamps else "         -"
        style = "bold red" if kind == "xrce.zero_fill" else ("yellow" if "." in kind else "")
        out.append(_line(f" {when} {kind:<22} {text}", style, width))
    return out or [_line(" no events", "dim", width)]


class UdpViews:
    """The UDP monitor's view set for :class:`~hilbench.dashboard.app.Dashboard`."""

    views = VIEWS
    titles = TITLES
    letters = {"o": "overview", "x": "xrce", "r": "rtps", "e": "events"}

    def render(self, dash, width: int, height: int) -> Group:
        tr: UdpTracker = dash.tracker
        body = {"overview": _overview, "xrce": _xrce, "rtps": _rtps, "events": _events}[dash.view](tr, width)
        dur = tr.duration
        head = _line(f" hilbench monitor  {dash.source}  [{dash.status()}]  {TITLES[dash.view]}  "
                     f"{tr.datagrams} datagrams" + (f" in {dur:.1f} s" if dur and tr.timestamps else ""), "bold",
                     width)
        keys = _line(" 1 overview  2 xrce  3 rtps  4 events  up/down scroll  q quit", "dim", width)
        room = max(0, height - 3)
        lines = body[dash.scroll:dash.scroll + room]
        lines += [Text("")] * (room - len(lines))
        return Group(head, _line("-" * min(width, 120), "dim", width), *lines, keys)

    def navigate(self, dash, key: str) -> bool:
        return False


VIEW_SET = UdpViews()

__all__ = ["TITLES", "VIEWS", "VIEW_SET", "UdpViews"]
