"""Wire formats: byte layouts, checksums, framing and streaming decoders (no I/O)."""
