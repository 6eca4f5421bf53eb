"""hmpc runtime: the controller contract (base), MPC, NMPC, PID, limits, actuation adapters
and loops. Imports ``models``; never imported by it.
"""
