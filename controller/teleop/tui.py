"""The operator station's terminal UI: live telemetry with ``rich``, keys from the terminal.

``rich`` (a dependency of hmpc for this screen) draws the telemetry panel and redraws it in
place (``rich.live.Live``); no escape codes are written by hand. Keys are read from the
terminal in cbreak mode (``termios``/``tty`` from the standard library; rich draws, it does
not read keys): :class:`TerminalKeys` turns the bytes into key names (``up``, ``left``,
``esc``, ``a``, ...) for ``operator.KeyboardOperator``.
"""

from __future__ import annotations

import math
import os
import select
import sys
import time

from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from hmpc.controller.teleop.link import Mode, TeleopCommand, Telemetry

#: escape sequences of the arrow keys (normal and application cursor mode) and Escape
_SEQUENCES = {
    b"\x1b[A": "up",
    b"\x1b[B": "down",
    b"\x1b[C": "right",
    b"\x1b[D": "left",
    b"\x1bOA": "up",
    b"\x1bOB": "down",
    b"\x1bOC": "right",
    b"\x1bOD": "left",
}
#: telemetry older than this is shown as stale [s] (five telemetry periods at 10 Hz)
TELEMETRY_STALE_S = 0.5
KEY_HELP = (
    "e engage  space/esc release dead-man  up/w throttle  down/s brake  left/a right/d "
    "steer  c centre  x release pedals  m MPC  t take over  q quit"
)


def parse_keys(data: bytes) -> list[str]:
    """Key names in ``data`` (bytes read from a terminal in cbreak mode)."""
    keys = []
    i = 0
    while i < len(data):
        if data[i] == 0x1B:
            seq = bytes(data[i : i + 3])
            if seq in _SEQUENCES:
                keys.append(_SEQUENCES[seq])
                i += 3
                continue
            keys.append("esc")
            i += 1
            continue
        ch = chr(data[i])
        keys.append(ch.lower() if ch.isalpha() else ch)
        i += 1
    return keys


class TerminalKeys:
    """Keys from a terminal without waiting (cbreak mode while in the ``with`` block)."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stdin
        self.fd = self.stream.fileno()
        self._saved = None

    def __enter__(self):
        import termios
        import tty

        if not os.isatty(self.fd):
            raise OSError("the keyboard operator needs a terminal on stdin")
        self._saved = termios.tcgetattr(self.fd)
        tty.setcbreak(self.fd)
        return self

    def __exit__(self, *exc):
        import termios

        if self._saved is not None:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)

    def read(self) -> list[str]:
        """Every key pressed since the last call (never blocks)."""
        data = b""
        while select.select([self.fd], [], [], 0)[0]:
            chunk = os.read(self.fd, 1024)
            if not chunk:
                break
            data += chunk
        return parse_keys(data)


def _fmt(x: float, spec: str, unit: str = "") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:{spec}}{unit}"


def render(
    t_s: float,
    cmd: TeleopCommand | None,
    tel: Telemetry | None,
    *,
    source: str,
    target: str,
    now_wall_s: float | None = None,
    last_key: str = "",
) -> Panel:
    """The telemetry panel: vehicle, command, link statistics, stop reason."""
    now = time.time() if now_wall_s is None else now_wall_s
    g = Table.grid(padding=(0, 2))
    g.add_column(style="bold cyan", no_wrap=True)
    g.add_column()
    if tel is None:
        g.add_row("vehicle", Text("no telemetry yet", style="yellow"))
    else:
        age = now - tel.t_send_s
        v = tel.vehicle
        stale = f"  [red]STALE {age * 1e3:.0f} ms[/red]" if age > TELEMETRY_STALE_S else ""
        g.add_row("speed", f"{_fmt(v.speed_mps, '.2f', ' m/s')}{stale}")
        g.add_row("steering", _fmt(v.steering_wheel_angle_rad, "+.3f", " rad (wheel)"))
        g.add_row("zone", f"{v.zone_name or '-'} ({v.zone})" if v.zone >= 0 else "-")
        g.add_row("pedal mode", v.pedal_mode or "-")
        g.add_row(
            "engaged",
            ("yes, MPC drives" if tel.mpc_in_control else "yes, operator drives")
            if tel.engaged
            else "[yellow]no[/yellow]",
        )
        rej = {k: n for k, n in tel.rejected.items() if n}
        g.add_row(
            "link",
            f"received {tel.received}  accepted {tel.accepted}  delivered "
            f"{tel.delivered}  lost {tel.lost}  rejected {sum(rej.values())}"
            + (f" {rej}" if rej else ""),
        )
        g.add_row(
            "latency",
            f"p50 {_fmt(tel.latency_p50_ms, '.2f', ' ms')}  p99 "
            f"{_fmt(tel.latency_p99_ms, '.2f', ' ms')}  max gap "
            f"{_fmt(tel.max_gap_ms, '.0f', ' ms')}",
        )
        g.add_row(
            "stop",
            "[red]" + f"{tel.stop.reason} at {tel.stop.t_s:.2f} s" + "[/red]"
            if tel.stop
            else "none",
        )
    if cmd is not None:
        if cmd.mode == Mode.PEDALS:
            what = (
                f"steering {cmd.values[0]:+.2f} rad  accel {cmd.values[1]:.2f}  "
                f"brake {cmd.values[2]:.2f}"
            )
        elif cmd.mode == Mode.REFERENCES:
            what = f"speed {cmd.values[0]:.2f} m/s  curvature {cmd.values[1]:+.4f} 1/m"
        else:
            what = cmd.mode.name.lower()
        dm = "held" if cmd.dead_man else "[red]RELEASED[/red]"
        g.add_row("command", f"{what}  dead-man {dm}")
    if last_key:
        g.add_row("last key", last_key)
    title = f"hmpc operator  {source} -> {target}  t {t_s:7.2f} s"
    parts: list[RenderableType] = [g]
    if source == "keyboard":
        parts.append(Text(KEY_HELP, style="dim"))
    return Panel(Group(*parts), title=title, title_align="left")


class OperatorScreen:
    """A live panel redrawn at most ``refresh_hz`` times a second (``rich.live.Live``)."""

    def __init__(self, source: str, target: str, refresh_hz: float = 10.0, console=None):
        self.source, self.target = source, target
        self.console = console or Console()
        self.min_dt_s = 1.0 / refresh_hz
        self._last = -math.inf
        self.live = Live(console=self.console, auto_refresh=False, transient=False)
        self.last_key = ""

    def __enter__(self):
        self.live.__enter__()
        return self

    def __exit__(self, *exc):
        self.live.__exit__(*exc)

    def update(
        self, t_s: float, cmd: TeleopCommand | None, tel: Telemetry | None, force: bool = False
    ) -> None:
        now = time.monotonic()
        if not force and now - self._last < self.min_dt_s:
            return
        self._last = now
        self.live.update(
            render(t_s, cmd, tel, source=self.source, target=self.target, last_key=self.last_key),
            refresh=True,
        )
