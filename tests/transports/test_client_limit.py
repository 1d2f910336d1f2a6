"""The eviction policy's measure: what a client on this machine left unread, seen from the server's side."""

from __future__ import annotations

import socket

import pytest

from hilbench.transports.client_limit import Eviction, ReadWatch, observe, peer_unread


@pytest.fixture
def pairs():
    """``make(n)``: n TCP connections on 127.0.0.1 as ``(server side, client side)``."""
    made = []
    listener = socket.create_server(("127.0.0.1", 0))

    def make(n):
        for _ in range(n):
            client = socket.create_connection(listener.getsockname(), timeout=5)
            server, _ = listener.accept()
            made.append((server, client))
        return made[-n:]

    yield make
    listener.close()
    for server, client in made:
        server.close()
        client.close()


def _send(sock: socket.socket, watch: ReadWatch, data: bytes) -> None:
    sock.sendall(data)
    watch.sent += len(data)


def test_the_kernel_tells_what_a_local_client_has_not_read(pairs):
    (s1, c1), (s2, c2), (s3, _c3) = pairs(3)
    s1.sendall(b"x" * 73)
    s2.sendall(b"y" * 10)
    assert c2.recv(4) == b"yyyy"
    # (loopback delivers at once: the bytes are in the client's socket when send returns)
    assert peer_unread([s1, s2, s3]) == [73, 6, 0]


def test_a_watch_keeps_the_time_a_client_stopped_reading_and_moves_on_while_it_reads(pairs):
    (s_deaf, _), (s_reader, c_reader), (s_quiet, _) = pairs(3)
    deaf, reader, quiet = ReadWatch(0.0), ReadWatch(0.0), ReadWatch(0.0)
    for sock, watch in ((s_deaf, deaf), (s_reader, reader)):
        _send(sock, watch, b"header")
    assert c_reader.recv(64) == b"header"
    entries = [(s_deaf, deaf, 0), (s_reader, reader, 0), (s_quiet, quiet, 0)]
    observe(entries, now=10.0)
    assert (deaf.since, reader.since, quiet.since) == (0.0, 10.0, 10.0)  # quiet: nothing was sent, none waits
    assert (deaf.taken, reader.taken) == (0, 6)
    for sock, watch in ((s_deaf, deaf), (s_reader, reader)):
        _send(sock, watch, b"more")
    observe(entries, now=20.0)  # the reader has not read "more" yet, and read nothing since the last look
    assert (deaf.since, reader.since) == (0.0, 10.0)
    assert c_reader.recv(64) == b"more"
    observe(entries, now=30.0)
    assert (deaf.since, reader.since) == (0.0, 30.0)
    assert deaf.unread_for(35.0) == 35.0 and reader.unread_for(35.0) == 5.0
    # The server's own queue counts as waiting too: a client whose socket is empty but whose queue is not is
    # not caught up.
    observe([(s_quiet, quiet, 100)], now=40.0)
    assert quiet.since == 30.0  # (caught up at the last look)


def test_eviction_takes_the_lowest_rank_then_the_longest_useless():
    clients = {"a": (1, 5.0), "b": (0, 9.0), "c": (0, 3.0), "d": None}
    policy = Eviction(lambda name, now: clients[name])
    assert policy.victim(list(clients), now=10.0) == "c"
    assert Eviction(lambda name, now: None).victim(list(clients), now=10.0) is None
