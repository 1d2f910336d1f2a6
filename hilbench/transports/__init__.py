"""Transports: moving bytes (ptys, the multi-drop serial line, sockets); no protocol knowledge."""
