"""The dashboard's views, as rich renderables of a tracker's state.

Every function here takes a :class:`Frame` (a consistent view of the tracker
at one moment, built under the monitor's lock) and a number of lines, and
returns a renderable exactly that tall, so the whole screen fits the terminal
(80x24 at least). Only ASCII is used for marks, so the screen reads the same
in any terminal and locale.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from rich.console import Group
from rich.text import Text

from hilbench.dashboard.widgets import line as _line
from hilbench.dashboard.widgets import ms as _ms
from hilbench.dashboard.widgets import pad as _pad
from hilbench.dashboard.widgets import row as _row
from hilbench.monitor.servo_bus.bus_state import (
    ServoBusState as BusTracker,  # a Protocol 2.0 or 1.0-framed tracker
)
from hilbench.monitor.servo_bus.devices import CONNECTED, DISCONNECTED, UNKNOWN, DeviceState, FieldValue
from hilbench.protocols.dynamixel import describe_error
from hilbench.transports.line_load import is_unpaced

VIEWS = ("devices", "models", "details", "log")
TITLES = {
    "devices": "Device overview",
    "models": "Model overview",
    "details": "Device details",
    "log": "Error log",
}
STATE_STYLE = {CONNECTED: "green", DISCONNECTED: "bold red", UNKNOWN: "yellow"}
STATE_MARK = {CONNECTED: "ok", DISCONNECTED: "DISC", UNKNOWN: "??"}


@dataclass
class Frame:
    """What one screen shows: the tracker plus the dashboard's selections, at bus time ``now``."""

    tracker: BusTracker
    now: float | None
    source: str
    status: str  # "live", "replay", "ended", ...
    view: str = "devices"
    device: int | None = None
    model: str | None = None
    scroll: int = 0
    width: int = 80
    models: dict[str, list[DeviceState]] = field(default_factory=dict)


def _ago(now: float | None, t: float | None, timed: bool) -> str:
    if t is None:
        return "never"
    if not timed or now is None:
        return "seen"
    dt = max(0.0, now - t)
    if dt < 1:
        return f"{dt * 1000:.0f} ms ago"
    if dt < 120:
        return f"{dt:.1f} s ago"
    return f"{dt / 60:.0f} min ago"


def short_model(name: str) -> str:
    """A compact model label for tables: ``MX-64``, ``XM430-W350``, ``?``."""
    if name == "<unknown>":
        return "?"
    return name.replace("(2.0)", "").replace("Wolfgang ", "")


# --------------------------------------------------------------------------- header and footer


def header(fr: Frame) -> list[Text]:
    """Two lines: source and device counts (red when a device is disconnected), then the bus figures."""
    tr = fr.tracker
    counts = tr.state_counts()
    bad = counts[DISCONNECTED] > 0
    bar = Text(style="bold white on red" if bad else "bold white on dark_green")
    bar.append(f" hilbench monitor  {fr.source} ")
    right = f" {counts[CONNECTED]} connected  {counts[DISCONNECTED]} disconnected"
    if counts[UNKNOWN]:
        right += f"  {counts[UNKNOWN]} unknown"
    room = fr.width - len(right) - 1
    bar.truncate(max(10, room), overflow="ellipsis", pad=True)
    bar.append(right + " ")
    bus = Text()
    recent = tr.recent(1.0) if tr.timestamps else None
    if recent is not None:
        span, nbytes, packets = recent
        bps = nbytes / span
        bus.append(f"{bps / 1000:6.1f} kB/s ")
        if tr.baud:
            load = bps * 10 / tr.baud
            if is_unpaced(load):  # more than the line carries at its rate: no load to speak of
                bus.append("unpaced ")
            else:
                bus.append(f"load {load:4.0%} ", style="bold yellow" if load > 0.8 else "")
        bus.append(f"{sum(packets.values()) / span:6.0f} pkt/s  ")
    else:
        bus.append(f"{tr.bytes / 1000:.1f} kB  {sum(tr.packet_counts().values())} packets  ")
    crc = tr.crc_errors
    bus.append(f"CRC {crc}", style="red" if crc else "")
    bus.append(f"  missed {tr.unanswered}", style="red" if tr.unanswered else "")
    main = tr.main_cycle()
    if main is not None and main.iv_n and main.iv_mean > 0:
        bus.append(f"  cycle {1 / main.iv_mean:.0f} Hz +-{main.jitter * 1000:.2f} ms")
    return [_line(bar, width=fr.width), _line(bus, width=fr.width)]


KEYS_HELP = "1 devices 2 models 3 details 4 log  <- -> select  up/dn scroll  q quit"


def footer(fr: Frame) -> list[Text]:
    """Two lines: the newest error, then the keys and the source's status."""
    log = fr.tracker.log
    newest = log.newest(1)
    err = _line(log.format(newest[0]), style="red", width=fr.width) if newest else _line("no errors", "green")
    keys = Text(KEYS_HELP, style="dim")
    status = f" [{fr.status}]"
    keys.truncate(max(10, fr.width - len(status)), overflow="ellipsis")
    keys.append(status, style="bold")
    return [err, _line(keys, width=fr.width)]


# --------------------------------------------------------------------------- views

def device_overview(fr: Frame, height: int) -> Group:
    """The start screen: one line per model with its counts, then every device as a tile."""
    lines: list[Text] = [_line(Text(TITLES["devices"], style="bold underline"), width=fr.width)]
    models = fr.models
    widths = (18, 9, 12, 7, max(4, fr.width - 18 - 9 - 12 - 7 - 4))
    lines.append(_row([("model", widths[0], "<"), ("connected", widths[1], ">"), ("disconnected", widths[2], ">"),
                       ("unknown", widths[3], ">"), ("IDs", widths[4], "<")], fr.width, "bold"))
    devs = [fr.tracker.devices[i] for i in sorted(fr.tracker.devices)]
    per_row = max(1, (fr.width + 1) // 10)
    tile_rows = -(-len(devs) // per_row) if devs else 1
    room_models = max(1, min(len(models), height - 3 - tile_rows))
    for name, group in list(models.items())[:room_models]:
        c = sum(d.state == CONNECTED for d in group)
        x = sum(d.state == DISCONNECTED for d in group)
        u = sum(d.state == UNKNOWN for d in group)
        style = "red" if x else "green" if c else "yellow"
        lines.append(_row([(Text(name, style=style), widths[0], "<"), (str(c), widths[1], ">"),
                           (Text(str(x), style="bold red" if x else ""), widths[2], ">"),
                           (str(u) if u else "", widths[3], ">"),
                           (",".join(str(d.id) for d in group), widths[4], "<")], fr.width))
    if len(models) > room_models:
        lines.append(_line(f"  ... {len(models) - room_models} more models (view 2)", "dim"))
    lines.append(Text(""))
    rows = max(1, height - len(lines))
    fits = len(devs) <= rows * per_row
    shown = devs if fits else devs[: (rows - 1) * per_row]
    for r in range(0, len(shown), per_row):
        row = Text()
        for k, dev in enumerate(shown[r : r + per_row]):
            flag = "!" if (dev.alert or dev.hardware_error or dev.last_error & 0x7F) else " "
            if k:
                row.append(" ")
            row.append(f"{dev.id:>3} ", style="bold")
            row.append(f"{STATE_MARK[dev.state]:<4}", style=STATE_STYLE[dev.state])
            row.append(flag, style="bold red")
        lines.append(_line(row, width=fr.width))
    if not fits:
        lines.append(_line(f"  ... {len(devs) - len(shown)} more devices (views 2 and 3)", "dim"))
    if not devs:
        lines.append(_line("  no devices seen yet", "dim"))
    return _pad(lines, height)


def model_overview(fr: Frame, height: int) -> Group:
    """Every device of the selected model, with its counters."""
    models = fr.models
    names = list(models)
    name = fr.model if fr.model in models else (names[0] if names else None)
    title = Text(TITLES["models"], style="bold underline")
    if name is not None:
        title.append(f": {name}  ({names.index(name) + 1}/{len(names)}, <- -> model)", style="bold")
    lines: list[Text] = [_line(title, width=fr.width)]
    if name is None:
        lines.append(_line("  no devices seen yet", "dim"))
        return _pad(lines, height)
    tr = fr.tracker
    cols = (("device", 14, "<"), ("state", 12, "<"), ("fw", 3, ">"), ("replies", 7, ">"), ("missed", 6, ">"),
            ("CRC", 4, ">"), ("err", 3, ">"), ("lat ms", 6, ">"), ("last seen", 11, ">"))
    lines.append(_row([(c, w, a) for c, w, a in cols], fr.width, "bold"))
    devs = models[name]
    room = max(1, height - 3)
    start = min(fr.scroll, max(0, len(devs) - room))
    for dev in devs[start : start + room]:
        lat = dev.latency() if tr.timestamps else None
        values = (
            f"{short_model(name)} ({dev.id})",
            Text(dev.state + (" (never)" if dev.never_answered else ""), style=STATE_STYLE[dev.state]),
            "-" if dev.firmware is None else str(dev.firmware),
            str(tr.replies(dev)),
            Text(str(dev.misses), style="red" if dev.misses else ""),
            Text(str(dev.crc_errors), style="red" if dev.crc_errors else ""),
            Text(str(dev.error_statuses), style="red" if dev.error_statuses else ""),
            _ms(lat["mean"]) if lat else "-",
            _ago(fr.now, dev.last_seen, tr.timestamps),
        )
        lines.append(_row([(v, w, a) for v, (_, w, a) in zip(values, cols, strict=True)], fr.width))
    if len(devs) > room:
        lines.append(_line(f"  rows {start + 1}-{min(len(devs), start + room)} of {len(devs)} (up/dn)", "dim"))
    return _pad(lines, height)


def _field_rows(fields: list[FieldValue]) -> list[FieldValue]:
    """Values read back first (the live state), then values written, then defaults (indirect items only if seen)."""
    read = [f for f in fields if f.how == "read"]
    written = [f for f in fields if f.how == "written"]
    defaults = [f for f in fields if not f.observed and not f.field.name.startswith("Indirect")]
    return read + written + defaults


def device_details(fr: Frame, height: int) -> Group:
    """A device list on the left; the selected device's identity, counters and control table."""
    tr = fr.tracker
    ids = sorted(tr.devices)
    dev_id = fr.device if fr.device in tr.devices else (ids[0] if ids else None)
    title = Text(TITLES["details"], style="bold underline")
    if dev_id is None:
        return _pad([_line(title, width=fr.width), _line("  no devices seen yet", "dim")], height)
    dev = tr.devices[dev_id]
    title.append(f": ID {dev.id}  {dev.model_name}", style="bold")
    body = height - 1
    # left: the device list, scrolled to keep the selection visible
    pos = ids.index(dev_id)
    first = min(max(0, pos - body // 2), max(0, len(ids) - body))
    left = []
    for i in ids[first : first + body]:
        d = tr.devices[i]
        t = Text(f"{'>' if i == dev_id else ' '}{i:>3} {STATE_MARK[d.state]:<4}", style=STATE_STYLE[d.state])
        if i == dev_id:
            t.stylize("reverse")
        left.append(t)
    # right: identity and counters, then the fields
    w = fr.width - 10
    lat = dev.latency() if tr.timestamps else None
    model = f"model {dev.model}" if dev.model is not None else "model unknown"
    if dev.model_from:
        model += f" ({dev.model_from})"
    state = Text(dev.state, style=STATE_STYLE[dev.state])
    if dev.never_answered:
        state.append(" - never answered", style="bold red")
    right = [
        Text.assemble(state, f"  {model}  fw {'-' if dev.firmware is None else dev.firmware}"
                      f"  seen {_ago(fr.now, dev.last_seen, tr.timestamps)}"),
        Text(f"requests {dev.requests}  replies {tr.replies(dev)}  missed {dev.misses} ({dev.consecutive} in a row)"
             f"  CRC {dev.crc_errors}  drops {dev.disconnects}"),
    ]
    describe = getattr(tr, "describe_error", describe_error)  # a Protocol 1.0 or Feetech bus has its own bits
    err = Text(f"ERR 0x{dev.last_error:02x} {describe(dev.last_error)}  errors {dev.error_statuses}  ",
               style="red" if dev.last_error else "")
    if dev.alert or dev.hardware_error:
        bits = ", ".join(dev.hardware_error_bits) or "read address 70 for the cause"
        err.append(f"ALERT: {bits}", style="bold red")
    elif dev.hardware_error == 0:
        err.append("hardware ok", style="green")
    right.append(err)
    right.append(Text("latency ms: " + (f"min {_ms(lat['min'])}  mean {_ms(lat['mean'])}  p99 {_ms(lat['p99'])}"
                                         f"  max {_ms(lat['max'])}  (n {lat['n']})" if lat else "-")))
    rows = _field_rows(dev.fields())
    cols = ((22, "<"), (20, "<"), (max(8, w - 22 - 20 - 2), "<"))
    right.append(_row([("item", cols[0][0], "<"), ("value", cols[1][0], "<"), ("source", cols[2][0], "<")], w, "bold"))
    room = max(1, body - len(right))
    start = min(fr.scroll, max(0, len(rows) - room))
    for fv in rows[start : start + room]:
        style = "" if fv.observed else "dim"
        how = fv.how if fv.how == "default" else f"{fv.how} {_ago(fr.now, fv.t, tr.timestamps)}"
        right.append(_row([(fv.field.name, cols[0][0], "<"), (Text(fv.text(), style=style or "bold"), cols[1][0], "<"),
                           (how, cols[2][0], "<")], w, style))
    if not rows:
        right.append(_line("nothing observed yet", "dim"))
    lines = [_line(title, width=fr.width)]
    for k in range(body):
        line = left[k].copy() if k < len(left) else Text(" " * 9)
        line.append(" ")
        if k < len(right):
            line.append(_line(right[k], width=w))
        lines.append(line)
    return _pad(lines, height)


def error_log(fr: Frame, height: int) -> Group:
    """Counts by kind, then the newest entries first as ``[+MM:SS.mmm] error: ...``."""
    log = fr.tracker.log
    title = Text(TITLES["log"], style="bold underline")
    title.append(f": {log.total} entries, newest first", style="bold")
    counts = Text()
    for kind, n in log.counts.items():
        if n:
            counts.append(f"{kind} {n}  ", style="red")
    lines: list[Text] = [_line(title, width=fr.width),
                         _line(counts if counts.plain else Text("nothing went wrong", "green"), width=fr.width)]
    room = height - 2
    entries = log.newest(room + fr.scroll)[fr.scroll :]
    for e in entries[:room]:
        lines.append(_line(log.format(e), width=fr.width))
    return _pad(lines, height)


RENDERERS = {"devices": device_overview, "models": model_overview, "details": device_details, "log": error_log}


def screen(fr: Frame, height: int = 24) -> Group:
    """The whole screen: header, the selected view, footer (exactly ``height`` lines)."""
    body = max(3, height - 4)
    return Group(*header(fr), RENDERERS[fr.view](fr, body), *footer(fr))


class DynamixelViews:
    """The Dynamixel bus monitor's view set for :class:`~hilbench.dashboard.app.Dashboard`.

    Keys: ``1``/``d`` devices, ``2``/``m`` models, ``3``/``i``/Enter details,
    ``4``/``e`` error log; Left/Right select the previous/next device (the
    model in the model overview; from the device overview they open details).
    """

    views = VIEWS
    titles = TITLES
    letters = {"d": "devices", "m": "models", "i": "details", "enter": "details", "e": "log"}

    def render(self, dash, width: int, height: int) -> Group:
        tr = dash.tracker
        fr = Frame(tr, dash.now(), dash.source, dash.status(), dash.view, dash.device, dash.model, dash.scroll,
                   width, tr.models())
        if dash.device is None or dash.device not in tr.devices:
            ids = sorted(tr.devices)
            dash.device = fr.device = ids[0] if ids else None
        return screen(fr, height)

    def navigate(self, dash, key: str) -> bool:
        if key not in ("left", "right", ",", ".", "p", "n"):
            return False
        step = 1 if key in ("right", ".", "n") else -1
        tr = dash.tracker
        if dash.view == "models":
            names = list(tr.models())
            if names:
                cur = names.index(dash.model) if dash.model in names else 0
                dash.model = names[(cur + step) % len(names)]
        else:
            ids = sorted(tr.devices)
            if ids:
                cur = ids.index(dash.device) if dash.device in ids else 0
                dash.device = ids[(cur + step) % len(ids)]
                if dash.view == "devices":
                    dash.view = "details"
        return True


VIEW_SET = DynamixelViews()
