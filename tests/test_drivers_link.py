"""Choosing the vehicle and authenticating the link: frames built and signed with pymavlink directly."""

from __future__ import annotations

import hashlib
import random

import pytest
from pymavlink.dialects.v10 import ardupilotmega as apm1
from pymavlink.dialects.v20 import ardupilotmega as apm

from drivers import LinkSettings, MavlinkDecoder, SourceError
from fuser.cli import main
from fuser.config import load_config

KEY = bytes(range(32))
NOW = 10 * 365 * 86_400 * 100_000  # signing clock (10 us units since 2015, 48 bits): any fixed time will do


def imu(time_usec: int, instance: int = 0):
    return apm.MAVLink_highres_imu_message(time_usec, 0.0, 0.0, -9.81, 0.01, 0.0, 0.0, 0.2, 0.0, 0.4, 0, 0, 0, 0, 0x1FF, instance)


def frame(msg, system: int = 1, component: int = 1, key: bytes | None = None, timestamp: int = NOW, link_id: int = 0, seq: int = 0) -> bytes:
    """A frame as a sender packs it with pymavlink: signed when ``key`` is given."""
    mav = apm.MAVLink(None, srcSystem=system, srcComponent=component)
    mav.seq = seq
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing = key, True
        mav.signing.timestamp, mav.signing.link_id = timestamp, link_id
    return bytes(msg.pack(mav))


def heartbeat(mav_type: int = 2, autopilot: int = 3):
    return apm.MAVLink_heartbeat_message(mav_type, autopilot, 0, 0, 4, 3)


def key_file(tmp_path, content: bytes = KEY) -> str:
    path = tmp_path / "key"
    path.write_bytes(content)
    return str(path)


def signed_decoder(tmp_path, content: bytes = KEY) -> MavlinkDecoder:
    return MavlinkDecoder(LinkSettings(lock_first_autopilot=False, signing_key_file=key_file(tmp_path, content)), signing_timestamp=NOW)


def times(samples) -> list[int]:
    return [s.t_ns // 1000 for s in samples]


# ---------------------------------------------------------------- choosing the vehicle

def test_locks_onto_the_first_autopilot_heartbeat_and_counts_everyone_else():
    decoder = MavlinkDecoder(LinkSettings())
    stream = (
        frame(imu(1_000), system=3)  # before any autopilot is heard
        + frame(heartbeat(6, 8), system=255, component=190)  # a ground station
        + frame(heartbeat(26, 3), system=3, component=154)  # a gimbal (MAV_TYPE_GIMBAL)
        + frame(heartbeat(18, 3), system=3, component=191)  # a companion computer (MAV_TYPE_ONBOARD_CONTROLLER)
        + frame(heartbeat(2, 3), system=3, component=1)  # the autopilot: a quadrotor running ArduPilot
        + frame(imu(2_000), system=3, component=1, seq=1)
        + frame(heartbeat(1, 12), system=4, component=1)  # a second vehicle (PX4 fixed wing)
        + frame(imu(2_500), system=4, component=1)  # its IMU is never mixed in
        + frame(imu(2_600), system=3, component=191)  # another component of the same system
        + frame(imu(3_000), system=3, component=1, seq=2)
    )
    assert times(decoder.feed(stream)) == [2_000, 3_000]
    assert (decoder.system, decoder.component) == (3, 1)
    assert decoder.stats["no_vehicle_yet"] == 4 and decoder.stats["other_sender"] == 3


@pytest.mark.parametrize("v1", [False, True], ids=["mavlink2", "mavlink1"])
def test_other_vehicles_heard_after_the_lock_are_named_and_not_fused(v1: bool):
    """Their frames are screened out undecoded (other_sender), but for their HEARTBEATs: a second autopilot is named,
    a ground station, a companion computer and a gimbal are not; their data is never mixed in."""
    second_vehicle = apm1.MAVLink_heartbeat_message(1, 12, 0, 0, 4, 3) if v1 else heartbeat(1, 12)  # PX4 fixed wing
    packed = (lambda msg, **ids: bytes(msg.pack(apm1.MAVLink(None, srcSystem=ids["system"], srcComponent=ids["component"])))) \
        if v1 else (lambda msg, **ids: frame(msg, **ids))
    decoder = MavlinkDecoder(LinkSettings())
    assert decoder.feed(frame(heartbeat(2, 3), system=3, component=1)) == []  # the vehicle: from now on others are screened
    stream = (
        frame(heartbeat(6, 8), system=255, component=190)  # a ground station
        + frame(heartbeat(18, 3), system=3, component=191)  # a companion computer
        + frame(heartbeat(26, 3), system=3, component=154)  # a gimbal
        + packed(second_vehicle, system=4, component=1)
        + frame(imu(2_500), system=4, component=1)
        + frame(imu(3_000), system=3, component=1, seq=1)
    )
    assert times(decoder.feed(stream)) == [3_000]
    assert decoder.other_vehicles == {(4, 1)}
    assert decoder.stats["other_sender"] == 5


def test_other_vehicles_named_are_capped():
    from drivers.mavlink_decode import MAX_OTHER_VEHICLES

    decoder = MavlinkDecoder(LinkSettings())
    decoder.feed(frame(heartbeat(), system=1))
    decoder.feed(b"".join(frame(heartbeat(), system=2 + k) for k in range(100)))
    assert len(decoder.other_vehicles) == MAX_OTHER_VEHICLES and decoder.stats["other_sender"] == 100


def test_a_component_given_waits_for_that_components_autopilot_heartbeat():
    decoder = MavlinkDecoder(LinkSettings(component=2))
    stream = frame(heartbeat(), system=1, component=1) + frame(heartbeat(), system=1, component=2) + frame(imu(5), system=1, component=2)
    assert times(decoder.feed(stream)) == [5]
    assert (decoder.system, decoder.component) == (1, 2)


def test_a_system_given_needs_no_heartbeat_and_takes_any_of_its_components():
    decoder = MavlinkDecoder(LinkSettings(system=7))
    stream = frame(imu(1), system=7, component=1) + frame(imu(2, 1), system=7, component=191) + frame(imu(3), system=8)
    assert times(decoder.feed(stream)) == [1, 2]
    assert decoder.stats["other_sender"] == 1


def test_without_the_lock_every_sender_is_used():
    decoder = MavlinkDecoder(LinkSettings(lock_first_autopilot=False))
    assert times(decoder.feed(frame(imu(1), system=5) + frame(imu(2), system=6))) == [1, 2]


# ---------------------------------------------------------------- signing

def test_a_correctly_signed_stream_is_used(tmp_path):
    decoder = signed_decoder(tmp_path)
    data = b"".join(frame(imu(1_000 + i), key=KEY, timestamp=NOW + 10 * i, seq=i) for i in range(3))
    assert times(decoder.feed(data)) == [1_000, 1_001, 1_002]
    assert decoder.stats["accepted"] == 3


@pytest.mark.parametrize(
    "bad, reason",
    [
        (frame(imu(500), key=bytes(32)), "bad_signature"),  # signed with another key
        (frame(imu(500), key=KEY)[:-6] + random.Random(7).randbytes(6), "bad_signature"),  # random signature bytes (the CRC still holds)
        (frame(imu(500)), "unsigned"),  # MAVLink 2 without a signature
        (bytes(apm1.MAVLink_highres_imu_message(500, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(apm1.MAVLink(None, 1, 1))), "unsigned"),
        (frame(imu(500), key=KEY, timestamp=NOW - 6_000_001, link_id=3), "replayed"),  # a new stream more than a minute old
    ],
    ids=["other_key", "random_signature", "mavlink2_unsigned", "mavlink1", "replayed"],
)
def test_unsigned_and_wrongly_signed_frames_are_refused(tmp_path, bad, reason):
    decoder = signed_decoder(tmp_path)
    good = frame(imu(1_000), key=KEY, timestamp=NOW + 1)
    assert times(decoder.feed(bad + good)) == [1_000]
    assert decoder.stats[reason] == 1 and decoder.stats["accepted"] == 1


def test_a_replayed_signed_frame_is_refused(tmp_path):
    decoder = signed_decoder(tmp_path)
    first, second = frame(imu(1_000), key=KEY, timestamp=NOW + 1), frame(imu(2_000), key=KEY, timestamp=NOW + 2, seq=1)
    assert times(decoder.feed(first + second + first)) == [1_000, 2_000]
    assert decoder.stats["replayed"] == 1


@pytest.mark.parametrize("timestamp, link_id", [(NOW + 1, 0), (NOW - 6_000_001, 3)], ids=["not_newer", "new_stream_too_old"])
def test_a_wrong_signature_is_a_bad_signature_whatever_its_timestamp(tmp_path, timestamp, link_id):
    """The signature is judged first: a frame of another key is not counted as replayed for an old timestamp."""
    decoder = signed_decoder(tmp_path)
    good = frame(imu(1_000), key=KEY, timestamp=NOW + 5)
    forged = frame(imu(1_100), key=bytes(32), timestamp=timestamp, link_id=link_id, seq=1)
    assert times(decoder.feed(good + forged)) == [1_000]
    assert decoder.stats["bad_signature"] == 1 and decoder.stats["replayed"] == 0


def test_a_forged_future_timestamp_does_not_lock_out_the_genuine_sender(tmp_path):
    """pymavlink stores a frame's signing timestamp before it checks the signature: one forged frame
    stamped far ahead makes every genuine frame after it look replayed. The decoder undoes that."""
    forged = frame(imu(900), key=KEY, timestamp=NOW + 10**9)[:-6] + bytes(6)
    genuine = frame(imu(1_000), key=KEY, timestamp=NOW + 1)
    bare = apm.MAVLink(None)
    bare.robust_parsing = True
    bare.signing.secret_key, bare.signing.timestamp = KEY, NOW
    assert [m.get_type() for m in bare.parse_buffer(forged + genuine)] == ["BAD_DATA", "BAD_DATA"]  # pymavlink alone
    decoder = signed_decoder(tmp_path)
    assert times(decoder.feed(forged + genuine)) == [1_000]
    assert decoder.stats["bad_signature"] == 1


def test_a_passphrase_file_gives_the_key_mavproxy_derives(tmp_path):
    """MAVProxy's ``signing setup PASSPHRASE``: the key is the SHA-256 digest of the passphrase."""
    mavproxy_key = hashlib.sha256(b"correct horse battery staple").digest()
    decoder = signed_decoder(tmp_path, b"correct horse battery staple\n")
    assert times(decoder.feed(frame(imu(7), key=mavproxy_key))) == [7]


def test_a_passphrase_line_of_32_bytes_is_a_passphrase_not_a_raw_key(tmp_path):
    """31 characters and the newline an editor or ``echo`` ends the file with: 32 bytes, but a line of text."""
    passphrase = b"thirty-one characters long, ok."
    assert len(passphrase + b"\n") == 32
    decoder = signed_decoder(tmp_path, passphrase + b"\n")
    assert times(decoder.feed(frame(imu(7), key=hashlib.sha256(passphrase).digest()))) == [7]


@pytest.mark.parametrize("key", [KEY[:-1] + b"\n", bytes(31) + b"\n", b"\xff" * 31 + b"\n"], ids=["text_like", "zeros", "not_utf8"])
def test_a_raw_key_ending_in_a_newline_byte_is_still_the_raw_key(tmp_path, key):
    """One random key in 256 ends in 0x0a: it is a raw key unless the whole file is printable UTF-8 text."""
    assert times(signed_decoder(tmp_path, key).feed(frame(imu(7), key=key))) == [7]


@pytest.mark.parametrize("content", [None, b"", b"\xff\xfe\x00bad utf-8 \xc3", bytes(4096), b"passphrase " * 500],
                         ids=["missing", "empty", "not_utf8", "nuls", "too_long"])  # /dev/zero was a passphrase of 4,096 NULs
def test_an_unusable_key_file_is_a_source_error_naming_the_setting(tmp_path, content):
    path = tmp_path / "key" if content is None else key_file(tmp_path, content)
    with pytest.raises(SourceError, match="link.signing_key_file"):
        MavlinkDecoder(LinkSettings(signing_key_file=str(path)))


# ---------------------------------------------------------------- settings

@pytest.mark.parametrize(
    "field, value",
    [("system", 0), ("system", 256), ("system", "1"), ("component", True), ("lock_first_autopilot", "yes"),
     ("dialect", "nosuch"), ("dialect", "../common"), ("signing_key_file", ""), ("request_rate_hz", 0.0),
     ("request_rate_hz", -5.0), ("request_rate_hz", float("nan")), ("request_rate_hz", float("inf")), ("request_rate_hz", 1001.0), ("request_rate_hz", 1e-300),
     ("request_rate_hz", "50"), ("request_rate_hz", True)],
)
def test_settings_are_validated_naming_the_key(field, value):
    with pytest.raises(ValueError, match=f"link.{field}"):
        LinkSettings(**{field: value})


def test_settings_come_from_the_config_file_and_the_command_line(tmp_path):
    toml = tmp_path / "f.toml"
    toml.write_text('[fuser]\nrate_hz = 50\n[fuser.link]\nsystem = 3\ndialect = "common"\n')
    assert load_config(toml).link == LinkSettings(system=3, dialect="common")
    toml.write_text("[fuser.link]\nsytem = 3\n")
    with pytest.raises(ValueError, match="link.sytem"):
        load_config(toml)


def test_a_bad_link_flag_is_one_line_and_exit_2(tmp_path, capsys):
    log = tmp_path / "x.tlog"
    log.write_bytes(b"")
    assert main(["replay", str(log), "-o", str(tmp_path / "o.mcap"), "--system", "300"]) == 2
    err = capsys.readouterr().err.strip()
    assert "link.system" in err and len(err.splitlines()) == 1
