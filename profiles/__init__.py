"""Bench profiles shipped with hilbench (installed as the ``hilbench.profiles`` package)."""
