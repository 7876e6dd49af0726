"""fuser.codec's JSON: byte for byte the standard library's encoder, and the standard library's parse.

The reference is Python's own ``json`` module, configured as ``dumps`` documents it
(compact separators, ASCII, NaN refused): the fast path must never hand out other bytes.
"""

import json
import math
import random
import struct
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.samples import GnssSample, ImuSample, SourceId
from fuser import codec
from fuser.codec import Estimate, dumps, encode_sample, loads, sample_json
from fuser.record import read_log

LOGS = Path(__file__).resolve().parent.parent / "logs"
REFERENCE = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def reference(obj) -> bytes:
    return REFERENCE.encode(obj).encode()


def _from_bits(bits: int) -> float:
    return struct.unpack("<d", bits.to_bytes(8, "little"))[0]


def awkward_floats(rng: random.Random) -> list[float]:
    """Every notation CPython's repr switches between, and the values either side of each switch."""
    values = [0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, 2.225073858507201e-308, 1.7976931348623157e308,
              0.1, 0.2, 0.3, 1 / 3, 2.0 ** 53, 2.0 ** 53 + 2, 2.0 ** 63, 2.0 ** 64, 9007199254740993.0]
    for e in range(-324, 309):  # powers of ten and their neighbours: the notation switches at 1e-4 and 1e16
        p = float(f"1e{e}")
        values += [p, -p, math.nextafter(p, 0.0), math.nextafter(p, math.inf), 1.5 * p, 9.999999999999999 * p]
    for _ in range(20_000):
        values.append(_from_bits(rng.getrandbits(64)))  # random bit patterns: every exponent equally
        values.append(_from_bits(rng.getrandbits(52) | (rng.getrandbits(1) << 63)))  # subnormals
        values.append(rng.uniform(-1.0, 1.0) * 10.0 ** rng.randint(-12, 20))  # the magnitudes telemetry has
        values.append(rng.uniform(1e-5, 1e-4) * rng.choice((1.0, -1.0)))  # where orjson writes fixed notation
    return [v for v in values if math.isfinite(v)]


INTEGERS = [0, 1, -1, 2**31, 2**53 + 1, 2**63 - 1, 2**63, -(2**63), -(2**63) - 1, 2**64 - 1, 2**64, -(2**64), 10**30, True, False]


def test_every_float_encodes_as_the_standard_library_does():
    values = awkward_floats(random.Random(17))
    fast = 0
    for v in values:
        expected = reference(v)
        out = codec._orjson_if_identical(v)
        assert out is None or out == expected, (v, out, expected)
        assert dumps(v) == expected
        fast += out is not None
    ordinary = sum(1e-4 <= abs(v) for v in values)
    assert fast >= 0.99 * ordinary  # the fast path is taken: above 1e-4 nothing differs


def test_floats_inside_messages():
    """As in an estimate: many floats in lists inside a dict, with integers near 2**63 beside them."""
    rng = random.Random(3)
    values = awkward_floats(rng)
    for i in range(0, len(values), 16):
        msg = {"t_ns": rng.choice(INTEGERS), "M": [values[i : i + 4], values[i + 4 : i + 8]], "Z": tuple(values[i + 8 : i + 16]),
               "counters": {"ticks": rng.choice(INTEGERS)}}
        assert dumps(msg) == reference(msg)


@pytest.mark.parametrize("value", INTEGERS, ids=repr)
def test_integers_near_the_64_bit_limits(value):
    assert dumps(value) == reference(value)
    assert dumps([value, -0.0, {"n": value}]) == reference([value, -0.0, {"n": value}])


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, [1.0, math.nan], {"z": [0.0, -math.inf]}], ids=repr)
def test_nan_and_infinity_are_refused(bad):
    with pytest.raises(ValueError):
        reference(bad)
    with pytest.raises(ValueError):
        dumps(bad)


@pytest.mark.parametrize("text", ["mavlink", "caf\u00e9", "\u2028", "\x00\x1f\x7f", 'quote " and \\ and /', "\U0001f681", "\b\f\n\r\t"])
def test_strings_are_escaped_as_the_standard_library_does(text):
    assert dumps({text: text}) == reference({text: text})


def test_keys_the_standard_library_converts():
    obj = {1: "a", 2.5: "b", False: "c", None: "d"}
    assert dumps(obj) == reference(obj)


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False) | st.text(),
    lambda children: st.lists(children, max_size=6) | st.dictionaries(st.text(max_size=8), children, max_size=6),
    max_leaves=40,
)


@settings(max_examples=200, deadline=None)
@given(JSON_VALUES)
def test_any_json_value(obj):
    assert dumps(obj) == reference(obj)
    assert loads(dumps(obj)) == json.loads(reference(obj))


@pytest.mark.parametrize("log", sorted(LOGS.glob("*.mcap")), ids=lambda p: p.stem)
def test_recorded_messages_reencode_to_their_stored_bytes(log):
    """Every message in logs/ (inputs, estimates, poses, truth) was written by the standard library's encoder:
    parsed and encoded again, it gives the same bytes; the estimates through Estimate too."""
    raw = read_log(log).raw
    assert len(raw) > 1000
    for m in raw:
        assert dumps(loads(m.data)) == m.data, m.topic
    for m in raw:
        if m.topic == "/estimate":
            assert Estimate.from_dict(json.loads(m.data)).to_json() == m.data


def test_loads_parses_as_the_standard_library_does():
    rng = random.Random(11)
    texts = [repr(v) for v in awkward_floats(rng)[::7]]
    for _ in range(20_000):  # more digits than a double holds, every exponent: correct rounding decides
        digits = "".join(rng.choice("0123456789") for _ in range(rng.randint(1, 40)))
        texts.append(f"{rng.choice(('', '-'))}{digits[0]}.{digits[1:] or '0'}e{rng.randint(-340, 320)}")
    texts += [repr(i) for i in INTEGERS if not isinstance(i, bool)] + ["NaN", "-Infinity", "[1e400]", '"\\ud800"', '{"a":1,"a":2}']
    for text in texts:
        expected, got = json.loads(text), loads(text.encode())
        assert type(got) is type(expected) and repr(got) == repr(expected), text


def _samples_with_nones():
    src = SourceId("mavlink", 1, 1, 0)
    yield ImuSample(1_764_000_000_123_456_789, (0.01, -0.02, 0.5), (0.1, 0.2, -9.8), None, src)
    yield GnssSample(5_000_000, 1, None, False, None, None, None, None, False, src)  # no fix: everything unknown
    yield GnssSample(5_000_000, 3, (1.5, -0.25, 0.0), False, None, 47.39, 8.54, 431.2, False, src)
    yield GnssSample(5_000_000, 3, (1.5, -0.25, 0.1), True, 0.3, 47.39, 8.54, 431.2, True, SourceId("null", 1, 1, 0))


def test_samples_encode_as_the_standard_library_does():
    """Every input of every log in logs/ (BROAD, PX4, simulated) and samples with each None field."""
    samples = [si for log in sorted(LOGS.glob("*.mcap")) for si in read_log(log).inputs()]
    samples += [(s, s.t_ns + 1_000_000) for s in _samples_with_nones()]
    fast = 0
    for s, receive_ns in samples:
        d = encode_sample(s, receive_ns)
        assert sample_json(s, receive_ns) == reference(d)
        fast += codec._orjson_if_identical(d, sum(v is None for v in d.values())) is not None
    assert fast > 0.9 * len(samples)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_a_sample_with_nan_beside_a_none_is_refused(bad):
    """orjson writes NaN as null: beside the null of a missing magnetometer it must still be refused."""
    s = ImuSample(0, (bad, 0.0, 0.0), (0.0, 0.0, -9.8), None, SourceId("mavlink", 1, 1, 0))
    with pytest.raises(ValueError):
        sample_json(s, 0)
