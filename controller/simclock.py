"""A simulated clock: time moves only when told, so a loop under test or in replay is repeatable.

One class serves both users: the drive loop's clock interface (``monotonic()``, ``time()``,
``sleep(s)`` that advances instantly; the log replay) and a callable clock that a test
advances by hand (``clock()``, ``advance(dt)``; the tele-operation link under test).
Imports nothing of hmpc.
"""

from __future__ import annotations


class SimClock:
    """Simulated time [s], starting at ``t_s``."""

    def __init__(self, t_s: float = 0.0):
        self.t_s = float(t_s)

    def __call__(self) -> float:
        return self.t_s

    def monotonic(self) -> float:
        return self.t_s

    def time(self) -> float:
        return self.t_s

    def sleep(self, seconds: float) -> None:
        """Advance by ``seconds`` [s] at once (a negative or zero sleep does nothing)."""
        if seconds > 0:
            self.t_s += float(seconds)

    def advance(self, dt_s: float) -> float:
        """Advance by ``dt_s`` [s]; returns the new time."""
        self.t_s += dt_s
        return self.t_s
