"""What a pty tells the bench about a client's line settings, and a medium taking a host's bytes at once."""

from __future__ import annotations

import os
import termios

import serial

from hilbench.pytest_plugin import wait_until
from hilbench.transports.port_state import SerialSettings
from hilbench.transports.pty import PtyPort, termios_settings
from hilbench.transports.serial_medium import SerialMedium

CMSPAR = getattr(termios, "CMSPAR", 0o10000000000)  # Linux; Python's termios lacks it


def test_rate_and_stop_bits_come_from_termios_even_for_custom_rates():
    with PtyPort("host") as ep, serial.Serial(ep.path, 4_500_000, stopbits=serial.STOPBITS_TWO):
        assert termios_settings(ep.slave_fd) == SerialSettings(4_500_000, 8, "N", 2.0)  # BOTHER via TCGETS2
        assert ep.client_baud() == 4_500_000


def test_data_bits_and_parity_come_from_the_clients_request():
    with PtyPort("host") as ep, serial.Serial(ep.path, 9600):
        assert ep.client_settings() == SerialSettings(9600)  # the pty forces CS8 and no parity
        assert ep.report_framing(termios.CS7 | termios.PARENB | termios.PARODD) == SerialSettings(9600, 7, "O", 1.0)
        assert ep.report_framing(termios.CS5 | termios.CSTOPB) == SerialSettings(9600, 5, "N", 1.5)
        assert ep.report_framing(termios.CS8 | termios.PARENB | CMSPAR) == SerialSettings(9600, 8, "S", 1.0)


def test_a_change_is_an_event_once():
    with PtyPort("host") as ep:
        events = []
        ep.port_state.set_listener(events.append)
        with serial.Serial(ep.path, 57_600) as ser:
            ep.client_baud()
            ep.client_baud()
            ser.baudrate = 115_200
            ep.client_baud()
        assert events == [SerialSettings(57_600), SerialSettings(115_200)]


class Sink:
    name = "sink"

    def __init__(self):
        self.got = []

    def on_bytes(self, data, t, baud):
        self.got.append(data)


def test_drain_host_takes_what_the_client_wrote():
    with PtyPort("host") as ep:
        medium = SerialMedium("line", 1_000_000)
        sink = Sink()
        medium.add_device(sink)
        medium.add_host(ep)
        fd = os.open(ep.path, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, b"abc")
            # Not started: nothing read the pty yet. drain_host takes it at once (run here as the
            # line's thread would), and delivery is queued for the line's thread.
            taken, end = medium.drain_host(ep)
            assert taken == 3 and end > 0
            assert medium.drain_host(ep)[0] == 0
            medium.start()
            wait_until(lambda: sink.got == [b"abc"])
        finally:
            os.close(fd)
            medium.close()


def test_a_change_between_custom_rates_is_seen():
    with PtyPort("host") as ep, serial.Serial(ep.path, 4_500_000) as ser:
        assert ep.client_baud() == 4_500_000
        ser.baudrate = 5_000_000  # BOTHER both times: the same tcgetattr answer
        assert ep.client_baud() == 5_000_000
