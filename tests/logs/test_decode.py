"""The vectorised decoder equals cantools bit for bit: on every frame of both real logs, and on
seeded random payloads of a DBC written here that exercises every layout (Motorola/Intel, odd
bit positions, signed, scale/offset, integer scaling, floats, extended ids, CAN FD, multiplexing).
"""

import numpy as np
import pytest
import cantools

from hmpc.models.logs.canlog import read_log
from hmpc.models.logs.dbc import load_dbc
from hmpc.models.logs.decode import KIND_UNKNOWN_ID, decode_frames, decode_frames_cantools
from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.frames import FrameTable

SEED = 20240611

DBC = """VERSION ""
BS_:
BU_: ECU

BO_ 256 BITS: 8 ECU
 SG_ FLAG : 1|1@0+ (1,0) [0|1] "" ECU
 SG_ BE_U12 : 13|12@0+ (1,0) [0|4095] "" ECU
 SG_ BE_S16 : 39|16@0- (0.01,-5) [0|0] "deg" ECU
 SG_ LE_S11 : 51|11@1- (0.5,0) [0|0] "" ECU

BO_ 257 LE64: 8 ECU
 SG_ WHOLE : 0|64@1+ (1,0) [0|0] "" ECU

BO_ 258 INTSCALE: 5 ECU
 SG_ INT_LIN : 0|10@1+ (2,-100) [0|0] "" ECU
 SG_ LE_ODD : 10|13@1+ (0.03125,-273) [0|0] "K" ECU
 SG_ BE_ODD : 29|9@0- (3,7) [0|0] "" ECU

BO_ 2147487744 EXTFLOAT: 8 ECU
 SG_ F32 : 0|32@1- (1,0) [0|0] "" ECU
 SG_ F32BE : 39|32@0- (2.5,1) [0|0] "" ECU

BO_ 260 DOUBLE: 8 ECU
 SG_ F64 : 7|64@0- (1,0) [0|0] "" ECU

BO_ 261 MUXED: 8 ECU
 SG_ MUX M : 0|4@1+ (1,0) [0|15] "" ECU
 SG_ A m0 : 8|16@1+ (0.1,0) [0|0] "" ECU
 SG_ B m1 : 15|12@0- (1,-3) [0|0] "" ECU
 SG_ C : 56|8@1+ (1,0) [0|0] "" ECU

BO_ 262 FD16: 16 ECU
 SG_ LO : 0|8@1+ (1,0) [0|0] "" ECU
 SG_ HI_BE : 87|12@0- (1,0) [0|0] "" ECU
 SG_ HI_LE : 100|20@1+ (0.1,0) [0|0] "" ECU

BO_ 263 FD64: 64 ECU
 SG_ SPAN9 : 4|64@1+ (1,0) [0|0] "" ECU
 SG_ TAIL : 511|8@0+ (0.5,1) [0|0] "" ECU

BO_ 264 SHORT3: 3 ECU
 SG_ S3 : 7|20@0- (0.001,0) [0|0] "" ECU

SIG_VALTYPE_ 2147487744 F32 : 1;
SIG_VALTYPE_ 2147487744 F32BE : 1;
SIG_VALTYPE_ 260 F64 : 2;
"""


@pytest.fixture(scope="module")
def syn_db():
    return cantools.database.load_string(DBC, database_format="dbc", strict=False)


def _table(rows, path="synthetic"):
    """FrameTable from (t, bus, id, extended, payload bytes) rows."""
    width = max(8, max(len(r[4]) for r in rows))
    data = np.zeros((len(rows), width), np.uint8)
    for i, r in enumerate(rows):
        data[i, : len(r[4])] = np.frombuffer(r[4], np.uint8)
    return FrameTable(
        np.array([r[0] for r in rows], float),
        np.array([r[1] for r in rows], np.int16),
        np.array([r[2] for r in rows], np.uint32),
        np.array([r[3] for r in rows], bool),
        np.array([len(r[4]) for r in rows], np.uint8),
        data,
        np.arange(1, len(rows) + 1, dtype=np.int64),
        path,
    )


def _bits(x: np.ndarray) -> np.ndarray:
    """float64 as raw bits (NaN canonicalised): equality of these is bit-exact equality."""
    x = np.where(np.isnan(x), np.nan, x)
    return x.view(np.uint64)


def _reference(db, msg, payloads):
    """cantools per frame: name -> float64 array (NaN where a mux signal is absent)."""
    cols = {s.name: np.full(len(payloads), np.nan) for s in msg.signals}
    for i, p in enumerate(payloads):
        for k, v in db.decode_message(msg.frame_id, p, decode_choices=False, scaling=True).items():
            cols[k][i] = v
    return cols


def _own_bits(payload: bytes, sig) -> int:
    """Independent bit reader: DBC Intel / Motorola (sawtooth) numbering, as integers."""
    n = len(payload) * 8
    if sig.byte_order == "little_endian":
        raw = (int.from_bytes(payload, "little") >> sig.start) & ((1 << sig.length) - 1)
    else:
        msb = (sig.start // 8) * 8 + 7 - sig.start % 8
        raw = (int.from_bytes(payload, "big") >> (n - msb - sig.length)) & ((1 << sig.length) - 1)
    if sig.is_signed and raw >> (sig.length - 1):
        raw -= 1 << sig.length
    return raw


def test_motorola_and_intel_bit_numbering_by_hand(syn_db):
    payload = bytes([0b00000010, 0x2A, 0xBC, 0, 0x80, 0x01, 0xF8, 0x3F])
    out = decode_frames(_table([(0.0, 0, 256, False, payload)]), syn_db, Problems())["BITS"]
    # FLAG: byte 0 bit 1.  BE_U12: msb at byte 1 bit 5 -> bits 0b101010 then 0b101111 -> 0xAAF
    assert out.signals["FLAG"][0] == 1.0
    assert out.signals["BE_U12"][0] == float(0b101010_101111)
    # BE_S16: bytes 4..5 = 0x8001 -> -32767 * 0.01 - 5
    assert out.signals["BE_S16"][0] == -32767 * 0.01 - 5
    # LE_S11: bits 51..61 = byte 6 bits 3..7 (0b11111) + byte 7 bits 0..5 (0b111111) -> -1 * 0.5
    assert out.signals["LE_S11"][0] == -0.5
    for sig in syn_db.get_message_by_name("BITS").signals:
        raw = _own_bits(payload, sig)
        assert out.signals[sig.name][0] == raw * sig.scale + sig.offset


@pytest.mark.parametrize(
    "name", ["BITS", "LE64", "INTSCALE", "EXTFLOAT", "DOUBLE", "MUXED", "FD16", "FD64", "SHORT3"]
)
def test_random_payloads_bit_exact_against_cantools(syn_db, name):
    rng = np.random.default_rng(SEED)
    msg = syn_db.get_message_by_name(name)
    payloads = [rng.integers(0, 256, msg.length, dtype=np.uint8).tobytes() for _ in range(400)]
    if msg.is_multiplexed():  # valid multiplexer values only, so cantools decodes every frame
        payloads = [bytes([p[0] & 0xF0 | (i % 2)]) + p[1:] for i, p in enumerate(payloads)]
    rows = [(0.01 * i, 0, msg.frame_id, msg.is_extended_frame, p) for i, p in enumerate(payloads)]
    problems = Problems()
    got = decode_frames(_table(rows), syn_db, problems, names=[name])[name]
    ref = _reference(syn_db, msg, payloads)
    assert len(problems) == 0
    assert len(got) == len(payloads)
    assert np.array_equal(got.where, np.arange(1, len(payloads) + 1))
    for sig in msg.signals:
        assert np.array_equal(_bits(got.signals[sig.name]), _bits(ref[sig.name])), sig.name
        if not sig.is_float and not msg.is_multiplexed():  # independent of cantools too
            own = np.array([_own_bits(p, sig) * sig.scale + sig.offset for p in payloads])
            assert np.array_equal(got.signals[sig.name], own), sig.name


def test_multiplexed_signals_absent_are_nan(syn_db):
    mux0 = bytes([0x00, 0x34, 0x12, 0, 0, 0, 0, 7])
    mux1 = bytes([0x01, 0x12, 0x30, 0, 0, 0, 0, 9])
    got = decode_frames(
        _table([(0.0, 0, 261, False, mux0), (0.1, 0, 261, False, mux1)]), syn_db, Problems()
    )["MUXED"]
    assert got.signals["A"][0] == 0x1234 * 0.1 and np.isnan(got.signals["A"][1])
    assert np.isnan(got.signals["B"][0]) and got.signals["B"][1] == 0x123 - 3
    assert list(got.signals["C"]) == [7.0, 9.0]


def test_round_trip_encode_then_decode(syn_db):
    """Random raw values -> cantools encode -> decode_frames gives raw*scale+offset exactly."""
    rng = np.random.default_rng(SEED + 1)
    for name in ("BITS", "INTSCALE", "FD16", "SHORT3"):
        msg = syn_db.get_message_by_name(name)
        raws, rows = [], []
        for i in range(200):
            raw = {}
            for s in msg.signals:
                lo, hi = (
                    (-(1 << (s.length - 1)), (1 << (s.length - 1)) - 1)
                    if s.is_signed
                    else (0, (1 << s.length) - 1)
                )
                raw[s.name] = int(rng.integers(lo, hi, endpoint=True))
            raws.append(raw)
            rows.append(
                (float(i), 1, msg.frame_id, False, msg.encode(raw, scaling=False, strict=False))
            )
        got = decode_frames(_table(rows), syn_db, Problems(), buses=[1])[name]
        for s in msg.signals:
            want = np.array([r[s.name] * s.scale + s.offset for r in raws], float)
            assert np.array_equal(got.signals[s.name], want), (name, s.name)


def test_cantools_path_gives_the_same_outputs(syn_db):
    rng = np.random.default_rng(SEED + 2)
    rows = []
    for i in range(300):
        msg = syn_db.messages[i % len(syn_db.messages)]
        p = bytearray(rng.integers(0, 256, msg.length, dtype=np.uint8).tobytes())
        if msg.is_multiplexed():
            p[0] &= 0xF1
        rows.append((0.001 * i, 0, msg.frame_id, msg.is_extended_frame, bytes(p)))
    a = decode_frames(_table(rows), syn_db, Problems())
    b = decode_frames_cantools(_table(rows), syn_db, Problems())
    assert a.keys() == b.keys() and len(a) == len(syn_db.messages)
    for name in a:
        assert np.array_equal(a[name].t_s, b[name].t_s)
        assert np.array_equal(a[name].where, b[name].where)
        for s in a[name].signals:
            assert np.array_equal(_bits(a[name].signals[s]), _bits(b[name].signals[s])), (name, s)


def test_unknown_message_name_is_an_input_error(syn_db):
    with pytest.raises(InputError, match="NOPE"):
        decode_frames(
            _table([(0.0, 0, 256, False, bytes(8))]),
            syn_db,
            Problems(),
            names=["NOPE"],
            dbc_path="x.dbc",
        )


def _overlapping(msg) -> bool:
    used = set()
    for s in msg.signals:
        msb = s.start if s.byte_order == "little_endian" else (s.start // 8) * 8 + 7 - s.start % 8
        bits = set(range(msb, msb + s.length))
        if used & bits:
            return True
        used |= bits
    return False


def _single_signal_reference(msg, sig, payloads):
    """cantools decoding one signal alone (for messages whose signals overlap)."""
    one = cantools.database.can.Message(
        frame_id=msg.frame_id, name=msg.name, length=msg.length, signals=[sig], strict=False
    )
    return np.array(
        [one.decode(p[: msg.length], decode_choices=False)[sig.name] for p in payloads], float
    )


@pytest.mark.parametrize("log,dbc", [("comma_log", "comma_dbc"), ("vcan_log", "vcan_dbc")])
def test_fast_path_equals_cantools_on_every_frame_of_the_real_logs(log, dbc, request):
    log, dbc = request.getfixturevalue(log), request.getfixturevalue(dbc)
    frames = read_log(log, Problems())
    db = load_dbc(dbc)
    problems = Problems()
    got = decode_frames(frames, db, problems)
    by_where = {int(w): i for i, w in enumerate(frames.where)}
    decoded = 0
    for name, dm in got.items():
        msg = db.get_message_by_name(name)
        rows = [by_where[int(w)] for w in dm.where]
        payloads = [frames.data[r, : frames.dlc[r]].tobytes() for r in rows]
        assert np.array_equal(dm.t_s, frames.t_s[rows])
        if _overlapping(msg):
            # cantools' whole-message codec cannot unpack overlapping signals ("unpacking
            # failed"); one-signal messages decode each signal as the DBC defines it
            for sig in msg.signals:
                want = _single_signal_reference(msg, sig, payloads)
                assert np.array_equal(_bits(dm.signals[sig.name]), _bits(want)), (name, sig.name)
        else:
            ref = _reference(db, msg, payloads)
            for sig in msg.signals:
                assert np.array_equal(_bits(dm.signals[sig.name]), _bits(ref[sig.name])), (
                    name,
                    sig.name,
                )
        decoded += len(dm)
    # every frame with a DBC id (and enough payload) was decoded, the rest counted as unknown
    unknown = {p.kind: p.count for p in problems}.get(KIND_UNKNOWN_ID, 0)
    short = sum(p.count for p in problems if p.kind.startswith("payload shorter"))
    assert decoded + unknown + short == len(frames)
    assert decoded > 25000


def test_bus_selection_and_time_order(syn_db):
    rows = [
        (0.0, 0, 256, False, bytes(8)),
        (0.1, 1, 256, False, bytes([2] + [0] * 7)),
        (0.2, 0, 256, False, bytes([2] + [0] * 7)),
        (0.3, 1, 999, False, bytes(8)),
    ]
    problems = Problems()
    got = decode_frames(_table(rows), syn_db, problems, buses=[0], names=["BITS"])["BITS"]
    assert list(got.t_s) == [0.0, 0.2] and list(got.bus) == [0, 0] and list(got.where) == [1, 3]
    assert list(got.signals["FLAG"]) == [0.0, 1.0]
    assert len(problems) == 0  # the unknown id 999 is on bus 1, not selected
    everything = decode_frames(_table(rows), syn_db, problems)
    assert list(everything) == ["BITS"] and len(everything["BITS"]) == 3
    assert [p.count for p in problems if p.kind == KIND_UNKNOWN_ID] == [1]


@pytest.mark.parametrize("names", [None, ["STEER_ANGLE_SENSOR", "WHEEL_SPEEDS", "GAS_PEDAL"]])
def test_block_boundaries_do_not_change_results(comma_log, comma_dbc, monkeypatch, names):
    """The decoder works in blocks of rows; tiny blocks must give the same arrays and problems."""
    import hmpc.models.logs.decode as decode

    frames = read_log(comma_log, Problems())
    db = load_dbc(comma_dbc)
    p_big, p_small = Problems(), Problems()
    big = decode_frames(frames, db, p_big, names=names)
    monkeypatch.setattr(decode, "_BLOCK_ROWS", 997)
    small = decode_frames(frames, db, p_small, names=names)
    assert big.keys() == small.keys()
    for name in big:
        for col in ("t_s", "bus", "where"):
            assert np.array_equal(getattr(big[name], col), getattr(small[name], col))
        for s in big[name].signals:
            assert np.array_equal(_bits(big[name].signals[s]), _bits(small[name].signals[s]))
    assert p_big.to_list() == p_small.to_list()
