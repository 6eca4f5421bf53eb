"""The keyboard operator in a real terminal (tmux): keys steer and accelerate the simulated car
through the link, and the screen shows the telemetry.

``hmpc operator --keyboard`` runs in a detached tmux session on a private tmux socket; this
test hosts the vehicle side (receiver + plant stand-in, real time) in a thread, sends keys with
``tmux send-keys`` and reads the screen with ``tmux capture-pane``. Waits poll for a condition
with a generous limit; nothing asserts on speed.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from hmpc.controller.teleop import link as L
from hmpc.controller.teleop.sink import PlantSink, serve
from hmpc.models.params import load_params

from _data import REPORT_PARAMS

TMUX = shutil.which("tmux")
pytestmark = [
    pytest.mark.realtime,
    pytest.mark.skipif(TMUX is None, reason="tmux is not installed (apt-get install -y tmux)"),
]
HMPC = str(Path(sys.executable).with_name("hmpc"))


def _wait(cond, what: str, limit_s: float = 30.0):
    t_end = time.monotonic() + limit_s
    while time.monotonic() < t_end:
        got = cond()
        if got:
            return got
        time.sleep(0.05)
    raise AssertionError(f"waited {limit_s:.0f} s for {what}")


class Tmux:
    def __init__(self, sock: Path):
        self.base = [TMUX, "-S", str(sock)]

    def __call__(self, *args) -> str:
        return subprocess.run(
            self.base + list(args), check=True, capture_output=True, text=True
        ).stdout

    def screen(self) -> str:
        return self("capture-pane", "-p", "-t", "op")

    def keys(self, *keys: str) -> None:
        for k in keys:
            self("send-keys", "-t", "op", k)
            time.sleep(0.03)  # one key per operator period, as typed


def test_keyboard_operator_in_tmux(tmp_path):
    key_path = tmp_path / "op.key"
    L.create_key(key_path)
    params = load_params(REPORT_PARAMS, require_model=True)
    rx = L.LinkReceiver(L.load_key(key_path), ("127.0.0.1", 0))
    sink = PlantSink(params)
    seen: list[L.TeleopCommand] = []
    done = threading.Event()

    step = sink.step

    def recording_step(poll, receiver):
        seen.extend(poll.commands)
        return step(poll, receiver)

    sink.step = recording_step
    th = threading.Thread(target=serve, args=(rx, sink), kwargs={"until": done.is_set})
    th.start()
    tmux = Tmux(tmp_path / "tmux.sock")
    cmd = (
        f"{HMPC} operator --key {key_path} --connect 127.0.0.1:{rx.address[1]} --keyboard "
        f"--json {tmp_path / 'run.json'}; echo EXIT=$?; sleep 60"
    )
    try:
        tmux("new-session", "-d", "-s", "op", "-x", "150", "-y", "30", cmd)
        _wait(lambda: "hmpc operator" in tmux.screen(), "the operator screen")
        tmux.keys("e")
        _wait(lambda: rx.engaged, "the vehicle side to be engaged")
        tmux.keys(*["Up"] * 6, *["Left"] * 3)
        pedals = lambda: [c for c in seen if c.mode == L.Mode.PEDALS]  # noqa: E731
        _wait(
            lambda: any(
                c.values[1] == pytest.approx(0.3) and c.values[0] == pytest.approx(0.3)
                for c in pedals()
            ),
            "accel 0.3 and steering 0.3 rad at the vehicle",
        )
        _wait(lambda: sink.state[3] > 1.0, "the simulated car to reach 1 m/s")

        def telemetry_shown():
            s = tmux.screen()
            return s if "yes, operator drives" in s and "throttle" in s else None

        screen = _wait(telemetry_shown, "telemetry on the screen")
        print(screen)
        for s in (
            "speed",
            "m/s",
            "zone",
            "pedal mode",
            "latency",
            "received",
            "dead-man held",
            "steering +0.30 rad",
        ):
            assert s in screen, (s, screen)
        assert rx.rejected == {r: 0 for r in L.REASONS}

        tmux.keys("Space")  # the dead-man latch released: the car stops
        _wait(lambda: rx.stop is not None, "a stop request")
        assert rx.stop.reason == "dead_man_released"
        _wait(lambda: "dead_man_released" in tmux.screen(), "the stop reason on the screen")
        _wait(lambda: sink.standstill_t_s is not None, "the car at standstill")
        tmux.keys("q")
        _wait(lambda: "EXIT=0" in tmux.screen(), "the operator to quit with status 0")
    finally:
        try:
            tmux("kill-server")
        except subprocess.CalledProcessError:
            pass
        done.set()
        th.join()
        rx.close()
