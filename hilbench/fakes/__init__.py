"""Emulated devices: behaviour on top of the protocol codecs and transports."""
