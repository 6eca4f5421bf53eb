"""Thin command-line front ends (the ``hmpc`` console script) and benchmarks.

All logic lives in ``models`` and ``controller``; nothing imports ``tools``.
"""
