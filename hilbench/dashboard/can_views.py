"""The CAN monitor's dashboard views: identifiers, CANopen nodes, decoded signals, event log.

Every view renders exactly the height it is given (80x24 at least), ASCII
marks only, like the other view sets (:mod:`hilbench.dashboard.servo_bus_views`).
Keys: ``1``/``i`` identifiers, ``2``/``n`` nodes, ``3``/``s``/Enter signals of
the selected identifier, ``4``/``e`` event log; Left/Right select the
identifier (the node in the node view).
"""

from __future__ import annotations

from rich.console import Group
from rich.text import Text

from hilbench.dashboard.widgets import line as _line
from hilbench.dashboard.widgets import ms as _ms
from hilbench.dashboard.widgets import pad as _pad
from hilbench.dashboard.widgets import row as _row
from hilbench.monitor.can.summary import stamp
from hilbench.monitor.can.tracker import CanTracker
from hilbench.transports.line_load import is_unpaced

VIEWS = ("ids", "nodes", "signals", "log")
TITLES = {"ids": "Identifiers", "nodes": "CANopen nodes", "signals": "Signals", "log": "Event log"}
KEYS_HELP = "1 ids 2 nodes 3 signals 4 log  <- -> select  up/dn scroll  q quit"
LEVEL_STYLE = {"info": "", "warn": "yellow", "error": "red"}


def _keys(tr: CanTracker) -> list[tuple[int, bool]]:
    return sorted(tr.ids, key=lambda k: (k[1], k[0]))


def header(tr: CanTracker, source: str, width: int, now: float | None) -> list[Text]:
    """Two lines: source and counts (red when a node is lost or error frames were seen), then the bus."""
    lost = [n for n in tr.nodes.values() if n.lost]
    bad = bool(lost) or tr.error_frames > 0
    bar = Text(style="bold white on red" if bad else "bold white on dark_green")
    bar.append(f" hilbench monitor  {source} ")
    right = f" {len(tr.ids)} IDs  {len(tr.nodes)} nodes" + (f"  {len(lost)} lost" if lost else "")
    bar.truncate(max(10, width - len(right) - 1), overflow="ellipsis", pad=True)
    bar.append(right + " ")
    bus = Text()
    recent = tr.recent(now)
    if recent is not None:
        span, bits, frames = recent
        bus.append(f"{frames / span:7.0f} frames/s ")
        if tr.baud:
            load = bits / (tr.baud * span)
            if is_unpaced(load, tr.peak_load):
                bus.append("unpaced ")
            else:
                bus.append(f"load {load:5.1%} ", style="bold yellow" if load > 0.7 else "")
                bus.append(f"(peak {tr.peak_load:5.1%}) ")
    else:
        bus.append(f"{tr.frames} frames  ")
    bus.append(f"err frames {tr.error_frames}", style="red" if tr.error_frames else "")
    if tr.lost_frames or tr.dropped_bytes:
        bus.append(f"  lost {tr.lost_frames}", style="yellow")
    bus.append(f"  SDO {tr.transfer_count}  NMT {tr.nmt_commands}")
    return [_line(bar, width=width), _line(bus, width=width)]


def footer(tr: CanTracker, status: str, width: int) -> list[Text]:
    """Two lines: the newest problem, then the keys and the source's status."""
    problems = [e for e in tr.events if e.level != "info"]
    if problems:
        e = problems[-1]
        first = _line(f"{stamp(tr, e.t)} {e.text}", LEVEL_STYLE[e.level], width)
    else:
        first = _line("no errors", "green", width)
    keys = Text(KEYS_HELP, style="dim")
    tail = f" [{status}]"
    keys.truncate(max(10, width - len(tail)), overflow="ellipsis")
    keys.append(tail, style="bold")
    return [first, _line(keys, width=width)]


def ids_view(tr: CanTracker, selected, width: int, height: int, scroll: int) -> Group:
    """Every identifier: name, count, rate, period, jitter, latest signals (or data)."""
    lines = [_line(Text(TITLES["ids"], style="bold underline"), width=width)]
    fixed = (10, 17, 6, 6, 7, 6)
    w = (*fixed, max(8, width - sum(fixed) - len(fixed)))
    lines.append(_row([("ID", w[0], "<"), ("what", w[1], "<"), ("count", w[2], ">"), ("Hz", w[3], ">"),
                       ("period", w[4], ">"), ("jitter", w[5], ">"), ("data / signals", w[6], "<")],
                      width, "bold"))
    keys = _keys(tr)
    rows = keys[scroll:]
    for key in rows[: max(0, height - 2)]:
        s = tr.ids[key]
        rate = s.rate() if tr.timestamps else None
        iv = s.intervals
        signals = " ".join(f"{k}={_fmt(v)}" for k, v in s.signals.items()) or s.data.hex(" ").upper()
        style = "reverse" if key == selected else ("yellow" if s.decode_errors or s.dlc_changes else "")
        lines.append(_row([(s.key, w[0], "<"), (s.name or s.label or "", w[1], "<"), (str(s.count), w[2], ">"),
                           (f"{rate:.1f}" if rate else "-", w[3], ">"),
                           (_ms(iv.mean if iv.n else None), w[4], ">"),
                           (_ms(iv.std if iv.n > 1 else None, 3), w[5], ">"), (signals, w[6], "<")], width, style))
    if not keys:
        lines.append(_line("no frames yet", "dim", width))
    return _pad(lines, height)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def nodes_view(tr: CanTracker, selected_node: int | None, width: int, height: int, now: float | None) -> Group:
    """CANopen nodes (state, heartbeat, misses, EMCY, SDO counts) and the latest SDO transfers."""
    lines = [_line(Text(TITLES["nodes"], style="bold underline"), width=width)]
    w = (5, 16, 9, 9, 7, 6, 6, max(10, width - 5 - 16 - 9 - 9 - 7 - 6 - 6 - 7))
    lines.append(_row([("node", w[0], ">"), ("NMT state", w[1], "<"), ("heartb.", w[2], ">"),
                       ("period", w[3], ">"), ("misses", w[4], ">"), ("boots", w[5], ">"), ("EMCY", w[6], ">"),
                       ("SDO up/down/abort, last EMCY", w[7], "<")], width, "bold"))
    for n in sorted(tr.nodes):
        node = tr.nodes[n]
        period = node.period()
        last = node.last_emcy
        extra = f"{node.sdo_uploads}/{node.sdo_downloads}/{node.sdo_aborts}"
        if last:
            extra += f"  {last['code']} {last['text']}"
        style = "bold red" if node.lost else ("reverse" if n == selected_node else "")
        lines.append(_row([(str(n), w[0], ">"), (node.state_name, w[1], "<"), (str(node.heartbeats), w[2], ">"),
                           (_ms(period, 0), w[3], ">"), (str(node.misses), w[4], ">"), (str(node.bootups), w[5], ">"),
                           (str(node.emcy), w[6], ">"), (extra, w[7], "<")], width, style))
    if not tr.nodes:
        lines.append(_line("no CANopen node heard yet (heartbeat, boot-up, EMCY or SDO)", "dim", width))
    lines.append(_line("", width=width))
    lines.append(_line(Text("SDO transfers", style="bold"), width=width))
    room = max(0, height - len(lines))
    for t in list(tr.transfers)[-room:] if room else []:
        name = tr.object_name(t.node, t.index, t.subindex) or ""
        what = f"abort 0x{t.abort:08X}" if t.abort else repr(t.value()) if t.value() is not None else f"{t.size} B"
        lines.append(_line(f"{stamp(tr, t.t_start)} node {t.node} {t.direction[:2]} 0x{t.index:04X}:{t.subindex:02X} "
                           f"{name} {t.kind} {what}", "yellow" if t.abort else "", width))
    return _pad(lines, height)


def signals_view(tr: CanTracker, selected, width: int, height: int, scroll: int) -> Group:
    """One identifier in detail: timing, data, decoded signals."""
    lines = [_line(Text(TITLES["signals"], style="bold underline"), width=width)]
    if selected is None or selected not in tr.ids:
        lines.append(_line("no frames yet", "dim", width))
        return _pad(lines, height)
    s = tr.ids[selected]
    rate = s.rate() if tr.timestamps else None
    lines.append(_line(f"{s.key}  {s.name or s.label or '(no name: give --dbc or --eds)'}  count {s.count}  "
                       f"{rate:.1f} Hz" if rate else f"{s.key}  {s.name or s.label or ''}  count {s.count}",
                       "bold", width))
    iv = s.intervals
    lines.append(_line(f"period mean {_ms(iv.mean if iv.n else None)} ms  min {_ms(iv.min if iv.n else None)}  "
                       f"max {_ms(iv.max if iv.n else None)}  jitter {_ms(iv.std if iv.n > 1 else None, 3)} ms  "
                       f"DLC {s.dlc} ({s.dlc_changes} changes)", width=width))
    lines.append(_line(f"data  {s.data.hex(' ').upper() or '-'}   from {', '.join(s.sources)}", width=width))
    if s.decode_errors:
        lines.append(_line(f"decode errors {s.decode_errors}: {s.last_decode_error}", "yellow", width))
    lines.append(_line("", width=width))
    items = list(s.signals.items())[scroll:]
    for name, value in items[: max(0, height - len(lines))]:
        lines.append(_row([(name, 24, "<"), (_fmt(value), max(8, width - 25), "<")], width))
    if not s.signals:
        lines.append(_line("no decoded signals (give --dbc FILE, --dbc PROFILE or --eds FILE:NODE)", "dim", width))
    return _pad(lines, height)


def log_view(tr: CanTracker, width: int, height: int, scroll: int) -> Group:
    """The event log, newest at the bottom."""
    lines = [_line(Text(TITLES["log"], style="bold underline"), width=width)]
    events = list(tr.events)
    room = max(0, height - 1)
    end = len(events) - scroll if scroll else len(events)
    for e in events[max(0, end - room): max(0, end)]:
        lines.append(_line(f"{stamp(tr, e.t)} {e.text}", LEVEL_STYLE[e.level], width))
    if not events:
        lines.append(_line("nothing happened yet", "dim", width))
    return _pad(lines, height)


class CanViews:
    """The CAN monitor's view set for :class:`~hilbench.dashboard.app.Dashboard`."""

    views = VIEWS
    titles = TITLES
    letters = {"i": "ids", "n": "nodes", "s": "signals", "enter": "signals", "e": "log"}

    def render(self, dash, width: int, height: int) -> Group:
        tr: CanTracker = dash.tracker
        keys = _keys(tr)
        if dash.model not in tr.ids:  # the dashboard's "model" slot holds the selected identifier
            dash.model = keys[0] if keys else None
        if dash.device is not None and dash.device not in tr.nodes and tr.nodes:
            dash.device = min(tr.nodes)
        now = dash.now()
        body = height - 4
        if dash.view == "ids":
            main = ids_view(tr, dash.model, width, body, dash.scroll)
        elif dash.view == "nodes":
            main = nodes_view(tr, dash.device, width, body, now)
        elif dash.view == "signals":
            main = signals_view(tr, dash.model, width, body, dash.scroll)
        else:
            main = log_view(tr, width, body, dash.scroll)
        return Group(*header(tr, dash.source, width, now), main, *footer(tr, dash.status(), width))

    def navigate(self, dash, key: str) -> bool:
        if key not in ("left", "right", ",", "."):
            return False
        step = 1 if key in ("right", ".") else -1
        tr: CanTracker = dash.tracker
        if dash.view == "nodes":
            nodes = sorted(tr.nodes)
            if nodes:
                cur = nodes.index(dash.device) if dash.device in nodes else 0
                dash.device = nodes[(cur + step) % len(nodes)]
            return True
        keys = _keys(tr)
        if keys:
            cur = keys.index(dash.model) if dash.model in keys else 0
            dash.model = keys[(cur + step) % len(keys)]
        return True


VIEW_SET = CanViews()

__all__ = ["VIEW_SET", "CanViews"]
