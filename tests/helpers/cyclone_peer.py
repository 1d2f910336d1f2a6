"""A standard DDS participant (Eclipse Cyclone DDS, the ``cyclonedds`` package) for the UDP tests.

Run as a separate process: ``python cyclone_peer.py CONFIG_JSON``; prints one JSON object.
Multicast off, 127.0.0.1 its only interface and peer. ``mode``:

- ``listen``: subscribe to ``topic`` (std_msgs/String or UInt32; ``reliable`` for a RELIABLE reader) for
  ``seconds``; report arrival times and values;
- ``echo``: publish ``count`` Strings on ``topic`` and collect what comes back on ``reply_topic``;
- ``publish``: publish ``count`` samples on ``topic`` at ``rate_hz`` (reliable).
"""

# No ``from __future__ import annotations``: cyclonedds resolves the field types of the IDL classes.
import json
import os
import sys
import time
from dataclasses import dataclass

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import uint32


@dataclass
class String_(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


@dataclass
class UInt32_(IdlStruct, typename="std_msgs::msg::dds_::UInt32_"):
    data: uint32


def main() -> None:
    cfg = json.loads(sys.argv[1])
    os.environ["CYCLONEDDS_URI"] = (
        "<CycloneDDS><Domain id='any'><General><Interfaces><NetworkInterface address='127.0.0.1'/></Interfaces>"
        "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
        "<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex><Peers><Peer address='127.0.0.1'/></Peers>"
        "</Discovery></Domain></CycloneDDS>")
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    types = {"std_msgs/String": String_, "std_msgs/UInt32": UInt32_}
    dp = DomainParticipant(cfg["domain"])
    best_effort = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1000))
    out: dict = {}
    reliable = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(1000))
    if cfg["mode"] == "listen":
        qos = reliable if cfg.get("reliable") else best_effort
        rd = DataReader(dp, Topic(dp, cfg["topic"], types[cfg.get("type", "std_msgs/String")]), qos=qos)
        got = []
        t_end = time.monotonic() + cfg["seconds"]
        while time.monotonic() < t_end:
            for s in rd.take(N=100):
                got.append((time.monotonic(), s.data))
            time.sleep(0.002)
        out = {"times": [t for t, _ in got], "values": [v for _, v in got]}
    elif cfg["mode"] in ("echo", "publish"):
        w = DataWriter(dp, Topic(dp, cfg["topic"], String_))
        rd = DataReader(dp, Topic(dp, cfg["reply_topic"], String_), qos=best_effort) if cfg.get("reply_topic") \
            else None
        # Wait until the node's reader matched ours (publication matched), at most 10 s.
        t_end = time.monotonic() + 10
        while time.monotonic() < t_end and w.get_matched_subscriptions() == []:
            time.sleep(0.01)
        if rd is not None:
            while time.monotonic() < t_end and rd.get_matched_publications() == []:
                time.sleep(0.01)
        matched = len(w.get_matched_subscriptions())
        sent = []
        for i in range(cfg["count"]):
            text = f"{cfg.get('prefix', 'ping')} {i}"
            w.write(String_(data=text))
            sent.append(text)
            time.sleep(1.0 / cfg.get("rate_hz", 20))
        back = []
        t_end = time.monotonic() + cfg.get("seconds", 3)
        while rd is not None and time.monotonic() < t_end and len(back) < len(sent):
            back += [s.data for s in rd.take(N=100)]
            time.sleep(0.005)
        out = {"matched": matched, "sent": sent, "back": back}
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
