"""hmpc runtime: MPC, limits, actuation adapters and loops.

Imports ``models``; never imported by it.
"""
