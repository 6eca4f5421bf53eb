"""Golden re-encoding: every STEERING_LKA and ACC_CONTROL frame openpilot sent in the bundled
comma2k19 minute is decoded and rebuilt with hmpc's builders, byte for byte, checksum included.
The frames come from the real log (hmpc's candump reader, decoded with hmpc's decoder); the
builder only sees the decoded command values, the request bit and the counter."""

from __future__ import annotations

import numpy as np
import pytest

from _data import PARAMS_DIR
from hmpc.controller.actuation import builders
from hmpc.controller.actuation.checksums import crc8_j1850, toyota_checksum
from hmpc.controller.actuation.profiles import load_profile
from hmpc.controller.actuation.safety import ToyotaLimits, ToyotaSteerCheck
from hmpc.models.errors import Problems
from hmpc.models.logs.canlog import read_log
from hmpc.models.logs.decode import decode_frames


@pytest.fixture(scope="module")
def sent(comma_log):
    frames = read_log(comma_log, Problems())
    prof = load_profile(PARAMS_DIR / "toyota_rav4_2017.actuation.yaml")
    out = {}
    for role, fid in (("steer_torque", 0x2E4), ("accel", 0x343)):
        rows = (frames.arb_id == fid) & (frames.bus == 0)
        out[role] = frames.take(rows)
    dec = decode_frames(
        frames, prof.db, Problems(), names=["STEERING_LKA", "ACC_CONTROL"], buses=[0]
    )
    return prof, out, dec


def _payloads(ft):
    return [bytes(ft.data[i, : ft.dlc[i]]) for i in range(len(ft))]


def test_checksum_scheme_matches_every_frame(sent):
    """The Toyota checksum, as implemented, equals the last byte of all 8000 sent frames."""
    _, ft, _ = sent
    for role, fid in (("steer_torque", 0x2E4), ("accel", 0x343)):
        pays = _payloads(ft[role])
        assert len(pays) > 1000
        bad = [p.hex() for p in pays if toyota_checksum(fid, p) != p[-1]]
        assert bad == []


def test_steering_lka_rebuilt_byte_for_byte(sent):
    prof, ft, dec = sent
    spec = prof.commands["steer_torque"]
    d = dec["STEERING_LKA"]
    pays = _payloads(ft["steer_torque"])
    assert len(d) == len(pays) == 6000
    assert np.unique(d.signals["STEER_REQUEST"]).tolist() == [0.0, 1.0]  # both states covered
    assert np.ptp(d.signals["STEER_TORQUE_CMD"]) > 100  # real torques
    for i, want in enumerate(pays):
        msg = builders.steering_lka(
            spec,
            d.signals["STEER_TORQUE_CMD"][i],
            bool(d.signals["STEER_REQUEST"][i]),
            int(d.signals["COUNTER"][i]),
        )
        assert msg.arbitration_id == 0x2E4 and msg.dlc == 5
        assert bytes(msg.data) == want, (
            f"frame {i}: built {bytes(msg.data).hex()} want {want.hex()}"
        )


def test_acc_control_rebuilt_byte_for_byte(sent):
    prof, ft, dec = sent
    spec = prof.commands["accel"]
    d = dec["ACC_CONTROL"]
    pays = _payloads(ft["accel"])
    assert len(d) == len(pays) == 2000
    assert d.signals["ACCEL_CMD"].min() < -0.5 < 0.5 < d.signals["ACCEL_CMD"].max()
    for i, want in enumerate(pays):
        msg = builders.acc_control(spec, d.signals["ACCEL_CMD"][i])
        assert bytes(msg.data) == want, (
            f"frame {i}: built {bytes(msg.data).hex()} want {want.hex()}"
        )


def test_profile_rates_match_the_log(sent):
    """Send rates in the profile are the rates the car saw (frames per second of the log;
    single periods jitter 4-19 ms because the device sends in bursts)."""
    prof, ft, _ = sent
    for role in ("steer_torque", "accel"):
        t = ft[role].t_s
        assert prof.commands[role].rate_hz == pytest.approx((len(t) - 1) / (t[-1] - t[0]), rel=0.01)


def test_counter_increments_by_one_mod_64(sent):
    """+1 per frame; the only exceptions are frames logged with the same receive time, whose
    order in the log is not their send order (a swap shows as +2, +63, +2)."""
    _, _, dec = sent
    d = dec["STEERING_LKA"]
    c = d.signals["COUNTER"].astype(int)
    step = np.diff(c) % 64
    odd = np.nonzero(step != 1)[0]
    assert len(odd) < 0.01 * len(step)
    t = d.t_s
    for i in odd:
        assert t[i] == t[i + 1] or t[i - 1] == t[i] or t[i + 1] == t[i + 2]


def test_crc8_j1850_check_value():
    # the catalogue check value of CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF)
    assert crc8_j1850(b"123456789") == 0x4B
    assert crc8_j1850(b"") == 0x00


def test_builder_refuses_values_that_do_not_fit(sent):
    prof, _, _ = sent
    spec = prof.commands["steer_torque"]
    with pytest.raises(builders.EncodeError):
        builders.steering_lka(spec, 40000, True, 0)  # would wrap in 16 signed bits
    with pytest.raises(builders.EncodeError):
        builders.acc_control(prof.commands["accel"], float("nan"))


def _panda_replay(comma_log, prof, perturb=None):
    """Every openpilot STEERING_LKA frame of the minute through hmpc's encoder-side check, in
    send order (6-bit counter unwrapped; the logger's receive batches reorder a few frames), on
    the 100 Hz send clock, with the EPS torque (STEER_TORQUE_SENSOR) and controls allowed
    (PCM_CRUISE.CRUISE_ACTIVE) as panda saw them. Returns the reasons of refused frames."""
    frames = read_log(comma_log, Problems())
    dec = decode_frames(
        frames,
        prof.db,
        Problems(),
        buses=[0],
        names=["STEERING_LKA", "STEER_TORQUE_SENSOR", "PCM_CRUISE"],
    )
    lka, eps, pcm = dec["STEERING_LKA"], dec["STEER_TORQUE_SENSOR"], dec["PCM_CRUISE"]
    step = np.diff(lka.signals["COUNTER"].astype(int)) % 64
    step[step > 32] -= 64
    seq = np.concatenate([[0], np.cumsum(step)])
    order = np.argsort(seq, kind="stable")
    t_send = lka.t_s[order[0]] + 0.01 * seq[order]
    torque = lka.signals["STEER_TORQUE_CMD"][order].astype(int)
    request = lka.signals["STEER_REQUEST"][order].astype(bool)
    if perturb is not None:
        torque[perturb[0]] += perturb[1]
    events = sorted(
        [(t, 0, i) for i, t in enumerate(eps.t_s)]
        + [(t, 1, i) for i, t in enumerate(pcm.t_s)]
        + [(t, 2, j) for j, t in enumerate(t_send)]
    )
    check, allowed, refused = ToyotaSteerCheck(ToyotaLimits()), False, []
    for t, kind, i in events:
        if kind == 0:
            check.eps_torque(eps.signals["STEER_TORQUE_EPS"][i])
        elif kind == 1:
            allowed = bool(pcm.signals["CRUISE_ACTIVE"][i])
        else:
            why = check.check(int(torque[i]), bool(request[i]), float(t), allowed)
            if why:
                refused.append((i, why))
    return refused, torque, request


def test_openpilot_steering_frames_pass_the_panda_checks(comma_log):
    """The checks at hmpc's encoder accept what the real car's panda accepted: all 6000 frames
    openpilot sent (engaged from t = 9 s, torques up to 630 units) pass; one frame pushed by
    100 units is refused (rate), as are the next frames until the torque is back near 0."""
    prof = load_profile(PARAMS_DIR / "toyota_rav4_2017.actuation.yaml")
    refused, torque, request = _panda_replay(comma_log, prof)
    assert len(torque) == 6000 and np.abs(torque).max() > 500 and request.sum() > 4000
    assert refused == []
    k = int(np.argmax(np.abs(torque)))
    refused, _, _ = _panda_replay(comma_log, prof, perturb=(k, 100 if torque[k] > 0 else -100))
    assert refused and refused[0][0] == k and "rate" in refused[0][1]
