"""Protocol codec: frame vectors computed by hand from the reference, round trips, arbitrary frames."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bar_policy.robot.actuators import ROBSTRIDE_MODELS
from bar_policy.robot.mit import encode_u16
from bar_policy.robstride import protocol as proto
from bar_policy.robstride.errors import CommandError, FrameError, RobstrideError

PI4 = 4 * math.pi


def sp(q=0.0, dq=0.0, kp=0.0, kd=0.0, tau=0.0):
    return proto.MitSetpoint(q=q, dq=dq, kp=kp, kd=kd, tau=tau)


# ---------------------------------------------------------------------------------------------------
# hand-computed MIT (type 1) vectors
# ---------------------------------------------------------------------------------------------------
def test_worked_example_rs02_section2():
    # robstride-protocol.md section 2: RS02, motor 1, q=1, dq=0, Kp=10, Kd=0.5, tau=1, P_max = 4*pi:
    # q:   (1 + 4pi) * 65535 / 8pi = 32767.5 + 65535/(8pi) = 32767.5 + 2607.59 = 35375.09 -> 35375 = 0x8A2F
    # dq:  (0 + 44) * 65535 / 88   = 32767.5                                   -> 32767 = 0x7FFF
    # Kp:  10 * 65535 / 500        = 1310.7                                    -> 1310  = 0x051E
    # Kd:  0.5 * 65535 / 5         = 6553.5                                    -> 6553  = 0x1999
    # tau: (1 + 17) * 65535 / 34   = 18 * 1927.5 = 34695.0                     -> 34695 = 0x8787
    # id = (1 << 24) | (0x8787 << 8) | 1 = 0x01878701
    frame, clamped = proto.encode_mit(1, "rs-02", sp(q=1.0, dq=0.0, kp=10.0, kd=0.5, tau=1.0))
    assert frame.arbitration_id == 0x01878701
    assert frame.data == bytes.fromhex("8A2F7FFF051E1999")
    assert clamped == ()


def test_rs05_vector():
    # RS05 (V 50, T 5.5, Kp 500, Kd 5), motor 15, q=-0.5, dq=2, Kp=20, Kd=1, tau=-1:
    # q:   (-0.5 + 4pi) * 65535 / 8pi = 32767.5 - 0.5 * 65535 / 8pi = 32767.5 - 1303.78 = 31463.72 -> 0x7AE7
    # dq:  (2 + 50) * 65535 / 100     = 52 * 655.35 = 34078.2                                  -> 0x851E
    # Kp:  20 * 65535 / 500           = 2621.4                                                 -> 0x0A3D
    # Kd:  1 * 65535 / 5              = 13107.0                                                -> 0x3333
    # tau: (-1 + 5.5) * 65535 / 11    = 4.5 * 5957.73 = 26809.77                               -> 0x68B9
    frame, clamped = proto.encode_mit(15, "rs-05", sp(q=-0.5, dq=2.0, kp=20.0, kd=1.0, tau=-1.0))
    assert frame.arbitration_id == 0x0168B90F
    assert frame.data == bytes.fromhex("7AE7851E0A3D3333")
    assert clamped == ()


def test_rs00_full_scale_and_midscale():
    # RS00 motor 22: q=0 and dq=0 -> 32767.5 -> 0x7FFF; Kp=500, Kd=5, tau=14 at the top of their
    # ranges -> 65535 = 0xFFFF (in range, not clamped); id = 0x01 FFFF 16
    frame, clamped = proto.encode_mit(22, "rs-00", sp(kp=500.0, kd=5.0, tau=14.0))
    assert frame.arbitration_id == 0x01FFFF16
    assert frame.data == bytes.fromhex("7FFF7FFFFFFFFFFF")
    assert clamped == ()


def test_out_of_range_is_clamped_and_reported():
    # q = 20 > 4pi -> 65535; Kp = -1 < 0 -> 0; tau = -100 < -17 -> 0 (id bits 23..8 = 0x0000)
    frame, clamped = proto.encode_mit(11, "rs-02", sp(q=20.0, kp=-1.0, tau=-100.0))
    assert clamped == ("q", "kp", "tau")
    assert frame.arbitration_id == 0x0100000B
    assert frame.data[:2] == b"\xff\xff" and frame.data[4:6] == b"\x00\x00"
    counter = proto.ClampCounter()
    counter.add(11, clamped)
    assert counter.total == 3 and counter.by_field["q"] == 1 and counter.by_id == {11: 3}


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("field", proto.MIT_FIELDS)
def test_non_finite_command_raises(field, bad):
    kw = {field: bad}
    with pytest.raises(CommandError, match=field):
        proto.encode_mit(11, "rs-02", sp(**kw))


def test_batch_shape_and_id_checks():
    ranges = proto.wire_ranges(["rs-02", "rs-00"])
    with pytest.raises(CommandError):
        proto.encode_mit_batch([11, 12], ranges, np.zeros((5, 3)))
    with pytest.raises(CommandError):
        proto.encode_mit(200, "rs-02", sp())


# ---------------------------------------------------------------------------------------------------
# other host frames
# ---------------------------------------------------------------------------------------------------
def test_simple_host_frames():
    # (type << 24) | (host 0xFD << 8) | motor 11
    assert proto.enable_frame(11) == proto.Frame(0x0300FD0B, bytes(8))
    assert proto.stop_frame(11) == proto.Frame(0x0400FD0B, bytes(8))
    assert proto.stop_frame(11, clear_faults=True) == proto.Frame(0x0400FD0B, b"\x01" + bytes(7))
    assert proto.set_zero_frame(11) == proto.Frame(0x0600FD0B, b"\x01" + bytes(7))
    assert proto.get_id_frame(11) == proto.Frame(0x0000FD0B, bytes(8))


def test_param_frames_manual_example():
    # manual section 4.1.14: read loc_kp 0x701E from motor 0x7F, host 0xFD
    assert proto.read_param_frame(0x7F, 0x701E) == proto.Frame(0x1100FD7F, bytes.fromhex("1E70000000000000"))
    # reply 0x11007FFD, 1E 70 00 00 | 00 00 F0 41 = 30.0f (0x41F00000 little-endian)
    reply = proto.decode_reply(0x11007FFD, bytes.fromhex("1E7000000000F041"))
    assert reply == proto.ParamReply(motor_id=0x7F, index=0x701E, status=0, raw=bytes.fromhex("0000F041"))
    assert reply.value() == 30.0


def test_param_write_caps():
    # torque cap 17.0 N*m -> 0x41880000 -> LE 00 00 88 41; index 0x700B LE = 0B 70
    assert proto.write_param_frame(11, 0x700B, 17.0) == proto.Frame(
        0x1200FD0B, bytes.fromhex("0B70000000008841")
    )
    # current cap 27.0 A -> 0x41D80000 -> LE 00 00 D8 41; index 0x7018 LE = 18 70
    assert proto.write_param_frame(11, 0x7018, 27.0) == proto.Frame(
        0x1200FD0B, bytes.fromhex("187000000000D841")
    )
    # run_mode (u8) = 5 -> byte 4 = 05, rest 0
    assert proto.write_param_frame(11, 0x7005, 5).data == bytes.fromhex("0570000005000000")
    # canTimeout (u32) = 20000 = 0x4E20 -> LE 20 4E 00 00
    assert proto.write_param_frame(11, 0x7028, 20000).data == bytes.fromhex("28700000204E0000")
    with pytest.raises(CommandError):
        proto.write_param_frame(11, 0x1234, 1.0)  # unknown index without dtype
    with pytest.raises(CommandError):
        proto.write_param_frame(11, 0x700B, math.nan)
    with pytest.raises(CommandError):
        proto.write_param_frame(11, 0x7005, 300)  # does not fit u8


# ---------------------------------------------------------------------------------------------------
# replies
# ---------------------------------------------------------------------------------------------------
def test_feedback_decoding_by_hand():
    # id 0x02800BFD: type 2; area2 0x800B: mode bits 23..22 = 0b10 (run), faults 0, motor 11; host 0xFD.
    # RS02 payload 8A2F 7FFF 8000 012C:
    #   q   = 35375 * 8pi/65535 - 4pi    (= 1.0 within one step)
    #   dq  = 32767 * 88/65535 - 44 = -44/65535
    #   tau = 32768 * 34/65535 - 17 = +17/65535
    #   T   = 0x012C = 300 -> 30.0 degC
    fb = proto.decode_reply(0x02800BFD, bytes.fromhex("8A2F7FFF8000012C"), models={11: "rs-02"})
    assert isinstance(fb, proto.Feedback)
    assert (fb.motor_id, fb.host_id, fb.mode, fb.faults, fb.model) == (11, 0xFD, 2, 0, "rs-02")
    assert fb.position == pytest.approx(35375 * 8 * math.pi / 65535 - PI4, abs=1e-12)
    assert abs(fb.position - 1.0) < 8 * math.pi / 65535
    assert fb.velocity == pytest.approx(-44 / 65535, abs=1e-12)
    assert fb.torque == pytest.approx(17 / 65535, abs=1e-12)
    assert fb.temperature == 30.0


def test_feedback_fault_bits_and_unknown_model():
    # faults overtemperature (bit 2) + uncalibrated (bit 5) = 0b100100 = 0x24; area2 = 0x8000|0x2400|0x0B
    fb = proto.decode_reply(0x02A40BFD, bytes.fromhex("7FFF7FFF7FFF0000"))
    assert fb.faults == 0x24 and fb.mode == 2
    assert proto.fault_names(fb.faults) == ("overtemperature", "uncalibrated")
    assert fb.model is None and math.isnan(fb.velocity) and math.isnan(fb.torque)


def test_feedback_encoder_matches_hand_vector():
    frame = proto.feedback_frame(11, "rs-02", position=1.0, velocity=0.0, torque=0.0, temperature=30.0)
    # position 1.0 -> 0x8A2F (as the command), velocity 0 -> 0x7FFF, torque 0 -> 0x7FFF, 30.0 degC -> 300
    assert frame == proto.Frame(0x02800BFD, bytes.fromhex("8A2F7FFF7FFF012C"))


def test_fault_device_id_and_report_frames():
    # type 21: motor 11 -> host 0xFD; fault word bit 3 (overvoltage) | bit 14 (stall) = 0x4008, warning 1
    f = proto.fault_frame(11, 0x4008, 1)
    assert f == proto.Frame(0x15000BFD, bytes.fromhex("0840000001000000"))
    rep = proto.decode_reply(*f)
    assert rep == proto.FaultReport(motor_id=11, fault_word=0x4008, warning_word=1)
    assert proto.fault_word_names(rep.fault_word) == ("overvoltage", "stall/I2t overload")
    # type 0 reply: motor 11 in bits 15..8, 0xFE in 7..0
    uid = bytes(range(8))
    assert proto.device_id_reply_frame(11, uid) == proto.Frame(0x00000BFE, uid)
    assert proto.decode_reply(0x00000BFE, uid) == proto.DeviceIdReply(motor_id=11, uid=uid)
    # a type-0 *request* is not a reply, and vice versa
    with pytest.raises(FrameError):
        proto.decode_reply(0x0000FD0B, bytes(8))
    with pytest.raises(FrameError):
        proto.decode_request(0x00000BFE, uid)
    # type 0x18 active report: tolerated, ignored
    assert proto.decode_reply(0x18000BFD, bytes(8)) == proto.ActiveReport(motor_id=11)


def test_decode_request_mit_and_simple():
    req = proto.decode_request(0x01878701, bytes.fromhex("8A2F7FFF051E1999"))
    assert req == proto.MitRequest(motor_id=1, raw=(0x8A2F, 0x7FFF, 0x051E, 0x1999, 0x8787))
    s = req.setpoint("rs-02")
    # Kp 1310 * 500/65535 = 9.99466..., Kd 6553 * 5/65535 = 0.49996...
    assert s.kp == pytest.approx(1310 * 500 / 65535) and s.kd == pytest.approx(6553 * 5 / 65535)
    w = proto.decode_request(*proto.write_param_frame(11, 0x700B, 17.0))
    assert (w.comm_type, w.motor_id, w.host_id, w.index) == (proto.CommType.PARAM_WRITE, 11, 0xFD, 0x700B)
    assert struct.unpack("<f", w.value_bytes)[0] == 17.0


@pytest.mark.parametrize(
    ("arb", "data", "ext"),
    [
        (0x123, bytes(8), False),  # 11-bit frame
        (0x02800BFD, bytes(7), True),  # short
        (0x02800BFD, bytes(9), True),  # long
        (0x1E000000, bytes(8), True),  # undefined type 30
        (0x01878701, bytes(8), True),  # a host MIT frame is not a reply
    ],
)
def test_invalid_replies_raise_frame_error(arb, data, ext):
    with pytest.raises(FrameError):
        proto.decode_reply(arb, data, is_extended_id=ext)


def test_scalar_feedback_encoder_equals_official_encoder():
    rng = np.random.default_rng(0)
    for lo, hi in ((-PI4, PI4), (-44.0, 44.0), (-5.5, 5.5), (-120.0, 120.0)):
        for x in rng.uniform(lo * 1.2, hi * 1.2, 2000):
            assert proto._u16(float(x), lo, hi) == int(encode_u16(float(x), lo, hi))


# ---------------------------------------------------------------------------------------------------
# properties
# ---------------------------------------------------------------------------------------------------
MODELS = sorted(ROBSTRIDE_MODELS)


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mit_round_trip_within_one_step(model, data):
    s = ROBSTRIDE_MODELS[model]
    lo = (-s.p_max, -s.v_max, 0.0, 0.0, -s.t_max)
    hi = (s.p_max, s.v_max, s.kp_max, s.kd_max, s.t_max)
    x = [data.draw(st.floats(a, b, allow_nan=False)) for a, b in zip(lo, hi, strict=True)]
    frame, clamped = proto.encode_mit(5, model, sp(*x))
    assert clamped == ()
    got = proto.decode_request(*frame).setpoint(model)
    for name, xi, a, b in zip(proto.MIT_FIELDS, x, lo, hi, strict=True):
        step = (b - a) / 65535
        yi = getattr(got, name)
        # truncation: decoded value is at most one step below the input, never above it (1e-9 slack)
        assert xi - step - 1e-9 <= yi <= xi + 1e-9 * max(1.0, abs(xi)), (name, xi, yi)


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_feedback_round_trip_within_one_step(model, data):
    s = ROBSTRIDE_MODELS[model]
    p = data.draw(st.floats(-s.p_max, s.p_max))
    v = data.draw(st.floats(-s.v_max, s.v_max))
    t = data.draw(st.floats(-s.t_max, s.t_max))
    temp = data.draw(st.floats(0.0, 200.0))
    mode = data.draw(st.integers(0, 2))
    faults = data.draw(st.integers(0, 63))
    frame = proto.feedback_frame(
        9, model, position=p, velocity=v, torque=t, temperature=temp, mode=mode, faults=faults
    )
    fb = proto.decode_reply(*frame, models={9: model})
    assert (fb.motor_id, fb.mode, fb.faults) == (9, mode, faults)
    assert abs(fb.position - p) <= 2 * s.p_max / 65535 + 1e-9
    assert abs(fb.velocity - v) <= 2 * s.v_max / 65535 + 1e-9
    assert abs(fb.torque - t) <= 2 * s.t_max / 65535 + 1e-9
    assert abs(fb.temperature - temp) <= 0.05 + 1e-9


_ids = st.one_of(
    st.integers(0, (1 << 29) - 1),
    st.builds(lambda t, rest: (t << 24) | rest, st.integers(0, 31), st.integers(0, (1 << 24) - 1)),
    st.integers(-5, 1 << 32),
)
_payloads = st.one_of(st.binary(min_size=8, max_size=8), st.binary(max_size=16))


@settings(max_examples=2000, deadline=None)
@given(
    arb=_ids, data=_payloads, ext=st.booleans(), models=st.sampled_from([None, {11: "rs-02", 12: "rs-05"}])
)
def test_arbitrary_frames_raise_only_frame_errors(arb, data, ext, models):
    for decode in (
        lambda: proto.decode_reply(arb, data, is_extended_id=ext, models=models),
        lambda: proto.decode_request(arb, data, is_extended_id=ext),
    ):
        try:
            out = decode()
        except FrameError:
            continue
        except Exception as exc:  # pragma: no cover - the property under test
            raise AssertionError(f"{type(exc).__name__} for {arb!r} {data!r}: {exc}") from exc
        assert isinstance(out, proto.Reply | proto.Request)
        if isinstance(out, proto.MitRequest):
            out.setpoint("rs-02")  # every u16 decodes to a finite value


def test_errors_are_typed():
    assert issubclass(FrameError, RobstrideError) and issubclass(FrameError, ValueError)
    from bar_policy.robstride import errors

    assert issubclass(errors.TimeoutError, TimeoutError) and issubclass(errors.TimeoutError, RobstrideError)
