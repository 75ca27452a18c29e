"""ComLib codec: known answers from the protocol reference, every message whole / split / byte by
byte / in garbage, status-code names, 12-bit packing, and a property-based fuzz test."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hal import comlib as cl
from hal.comlib import Ep0, Rbas, Rfmc
from hal.errors import DeviceError, ProtocolError, RadarError
from hal.waveform import d2g_frontend

# --- known answers (reference/d2g-comlib.md, "Minimal host session") ---------------------------


def test_requests_match_the_reference_bytes():
    ep = 1
    assert cl.request(0, Ep0.QUERY_ENDPOINT_INFO) == bytes.fromhex("5A00010000DBE0")
    assert cl.request(0, Ep0.QUERY_FW_INFO) == bytes.fromhex("5A00010001DBE0")
    assert cl.request(ep, Rbas.SET_AUTOMATIC_TRIGGER, bytes(4)) == bytes.fromhex("5A0105000200000000DBE0")
    assert cl.request(ep, Rbas.GET_DEVICE_INFO) == bytes.fromhex("5A01010022DBE0")
    fmt = cl.FrameFormat(64, 21, 1, 2)
    assert cl.encode_payload(ep, fmt.encode()) == bytes.fromhex("5A010B00414000000015000000" "0102DBE0")
    start = (200_000).to_bytes(4, "little")
    assert cl.request(ep, Rbas.SET_AUTOMATIC_TRIGGER, start) == bytes.fromhex("5A010500" "02400D0300" "DBE0")
    assert cl.request(ep, Rbas.GET_FRAME_DATA, b"\x01") == bytes.fromhex("5A0102000101DBE0")
    assert cl.encode_status(1, 0) == bytes.fromhex("5B010000")


def test_endpoint_tag_is_sent_little_endian():
    assert cl.tag_code("RBAS") == 0x52424153
    payload = cl.encode_endpoint_list([("RBAS", 1), ("RFMC", 1)])
    assert payload[2:6] == bytes.fromhex("53414252")
    recs = cl.parse_endpoint_list(payload)
    assert [(r.number, r.tag, r.version) for r in recs] == [(1, "RBAS", 1), (2, "RFMC", 1)]


def test_twelve_bit_pairs_follow_the_reference_formula():
    b0, b1, b2 = 0x34, 0x12, 0xAB
    assert cl.unpack12(bytes((b0, b1, b2)), 2).tolist() == [b0 + 256 * (b1 & 0x0F), (b1 >> 4) + 16 * b2]
    assert cl.pack12(np.array([0x234, 0xAB1])) == bytes((b0, b1, b2))


def _reference_unpack(buf: bytes, count: int, bits: int = 12) -> list[int]:
    """One continuous LSB-first bit stream, sample k at bits [k*bits, (k+1)*bits): the reference's words."""
    stream = int.from_bytes(buf, "little")
    return [(stream >> (k * bits)) & ((1 << bits) - 1) for k in range(count)]


@pytest.mark.parametrize("count", [1, 2, 3, 7, 64, 2688])
def test_unpack_matches_a_bit_stream_reference(count):
    rng = np.random.default_rng(count)
    buf = rng.integers(0, 256, cl.packed_len_12(count), dtype=np.uint8).tobytes()
    assert cl.unpack12(buf, count).tolist() == _reference_unpack(buf, count)
    v = rng.integers(0, 4096, count)
    assert cl.unpack12(cl.pack12(v), count).tolist() == v.tolist()


def test_frame_layout_and_centring_for_64x21():
    n_s, n_c = 64, 21
    x = (np.arange(2 * n_s * n_c) * 7 + 5) % 4096  # unsigned ADC counts in wire order
    head = cl.FRAME_HEADER.pack(Rbas.FRAME_DATA, 9, n_c, 1, n_s, 1, 1, 12, 0)
    payload = head + cl.pack12(x)
    assert len(payload) == 4050 == cl.frame_payload_len(n_c, n_s)
    assert len(cl.encode_payload(1, payload)) == 4056
    assert cl.encode_payload(1, payload)[:4] == bytes.fromhex("5A01D20F")
    h, i, q = cl.parse_frame(payload)
    assert h.frame_number == 9 and (h.n_chirps, h.n_samples, h.n_rx) == (n_c, n_s, 1)
    assert i.dtype == np.int16 and i.shape == (1, n_c, n_s) == d2g_frontend().frame_shape
    c, s = np.meshgrid(np.arange(n_c), np.arange(n_s), indexing="ij")
    assert np.array_equal(i[0], x[128 * c + s] - 2048)
    assert np.array_equal(q[0], x[128 * c + 64 + s] - 2048)


@pytest.mark.parametrize("data_format", [1, 2])
def test_frame_encode_parse_round_trip(data_format):
    rng = np.random.default_rng(3)
    i = rng.integers(-2048, 2048, (1, 21, 64)).astype(np.int16)
    q = rng.integers(-2048, 2048, (1, 21, 64)).astype(np.int16)
    h, i2, q2 = cl.parse_frame(cl.encode_frame(123456, i, q, data_format=data_format))
    assert h.frame_number == 123456 and h.data_format == data_format
    assert np.array_equal(i, i2) and np.array_equal(q, q2)


def test_frame_with_wrong_length_or_type_is_malformed():
    i = np.zeros((1, 21, 64), np.int16)
    good = cl.encode_frame(1, i, i)
    for bad in (good[:-1], good + b"\x00", b"\x01" + good[1:], good[:10]):
        with pytest.raises(cl.MalformedMessageError):
            cl.parse_frame(bad)
    real_only = bytearray(good)
    real_only[15] = 0
    with pytest.raises(cl.MalformedMessageError, match="data_format"):
        cl.parse_frame(bytes(real_only))


# --- replies ----------------------------------------------------------------------------------


def test_reply_round_trips():
    di = cl.DeviceInfo(24_000_000, 24_250_000, 1, 1, 7, 1, 1, 2, 0, 1, "Distance2Go")
    assert cl.DeviceInfo.parse(di.encode()) == di
    assert len(di.encode()) >= 17
    fw = cl.FirmwareInfo(1, 2, 3, "D2G")
    assert cl.FirmwareInfo.parse(fw.encode()) == fw
    old = cl.FirmwareInfo(1, 0, 7)  # old firmware sends only the 7-byte fixed part
    assert len(old.encode()) == 7 and cl.FirmwareInfo.parse(old.encode()) == old
    ff = cl.FrameFormat(64, 21, 1, 2)
    assert cl.FrameFormat.parse(ff.encode()) == ff
    fm = cl.FmcwConfig(24_025_000, 24_225_000, 0, 7)
    assert cl.FmcwConfig.parse(fm.encode()) == fm
    assert cl.parse_u32_reply(cl.encode_u32_reply(Rbas.MIN_INTERVAL, 47100), Rbas.MIN_INTERVAL, "x") == 47100
    assert cl.parse_sensor_reply(cl.encode_sensor_reply(Rbas.TEMPERATURE, 0, -1250), Rbas.TEMPERATURE, "t") == (0, -1250)


@pytest.mark.parametrize(
    "parse, data",
    [
        (cl.DeviceInfo.parse, bytes([Rbas.DEVICE_INFO]) + bytes(10)),
        (cl.FirmwareInfo.parse, b"\x01\x00"),
        (cl.FrameFormat.parse, bytes([Rbas.FRAME_FORMAT]) + bytes(11)),
        (cl.FmcwConfig.parse, bytes([Rfmc.GET_CONFIGURATION]) + bytes(10)),
        (cl.parse_endpoint_list, b"\x00\x02" + bytes(6)),
        (lambda d: cl.parse_u32_reply(d, Rbas.MIN_INTERVAL, "min"), bytes([Rbas.CHIRP_DURATION]) + bytes(4)),
    ],
)
def test_malformed_replies_raise_the_declared_error(parse, data):
    with pytest.raises(cl.MalformedMessageError):
        parse(data)


def test_request_errors():
    with pytest.raises(cl.RequestError):
        cl.encode_payload(1, b"")
    with pytest.raises(cl.RequestError):
        cl.encode_payload(256, b"\x00")
    with pytest.raises(cl.RequestError):
        cl.pack12(np.array([4096]))


# --- status codes ---------------------------------------------------------------------------------

ENDPOINT_CODES = {
    0x0002: "BusyError",
    0x0003: "IncompatibleModeError",
    0x0004: "NoFrameReadyError",
    0x0005: "FrameIntervalError",
    0x0006: "NoSuchAntennaError",
    0x0007: "NoSuchSensorError",
    0x0008: "UnsupportedFrameFormatError",
    0x0009: "FrequencyRangeError",
    0x000A: "TxPowerRangeError",
    0x000B: "SignalPartError",
    0x0020: "FmcwDirectionError",
    0x0050: "SampleRateError",
    0x0051: "AdcResolutionError",
    0xFFFF: "InvalidPayloadError",
}
FRAMING_CODES = {
    0x0001: "IncompleteMessageError",
    0x0002: "BadStartByteError",
    0x0003: "NoSuchEndpointError",
    0x0005: "EmptyPayloadError",
    0x0006: "PayloadTooLargeError",
    0x0007: "BadEndMarkerError",
    0xFFFF: "UnknownCommandError",
}


@pytest.mark.parametrize("endpoint, table", [(1, ENDPOINT_CODES), (3, ENDPOINT_CODES), (0, FRAMING_CODES)])
def test_every_status_code_has_a_named_error(endpoint, table):
    assert cl.status_error(endpoint, 0) is None
    for code, name in table.items():
        err = cl.status_error(endpoint, code, "set frame format")
        assert type(err).__name__ == name
        assert isinstance(err, cl.StatusError) and isinstance(err, ProtocolError)
        assert isinstance(err, DeviceError) and isinstance(err, RadarError)
        assert err.code == code and err.endpoint == endpoint
        assert f"0x{code:04X}" in str(err) and "set frame format" in str(err)
    base = cl.FramingStatusError if endpoint == 0 else cl.EndpointStatusError
    assert all(isinstance(cl.status_error(endpoint, c), base) for c in table)


def test_chip_range_and_unknown_codes():
    for code in (0x0100, 0x0120, 0x0135):
        assert type(cl.status_error(1, code)) is cl.ChipError
    for ep, code in ((1, 0x0001), (1, 0x0136), (0, 0x0004), (0, 0x1234)):
        assert type(cl.status_error(ep, code)) is cl.UnknownStatusError


# --- the stream decoder -----------------------------------------------------------------------------


def _corpus() -> list[cl.Message]:
    rng = np.random.default_rng(7)
    i = rng.integers(-2048, 2048, (1, 21, 64)).astype(np.int16)
    q = rng.integers(-2048, 2048, (1, 21, 64)).astype(np.int16)
    return [
        cl.Payload(0, bytes([Ep0.QUERY_ENDPOINT_INFO])),
        cl.Payload(0, cl.encode_endpoint_list([("RBAS", 1), ("RADX", 1), ("RFMC", 1)])),
        cl.Payload(0, cl.FirmwareInfo(1, 2, 3, "fw").encode()),
        cl.Payload(1, bytes([Rbas.GET_FRAME_DATA, 1])),
        cl.Payload(1, bytes([Rbas.SET_AUTOMATIC_TRIGGER]) + (200000).to_bytes(4, "little")),
        cl.Payload(1, cl.DeviceInfo(24_000_000, 24_250_000, 1, 1, 7, 1, 1, 1, 0, 1, "D2G").encode()),
        cl.Payload(1, cl.FrameFormat(64, 21, 1, 2).encode()),
        cl.Payload(1, cl.encode_u32_reply(Rbas.MIN_INTERVAL, 47100)),
        cl.Payload(1, cl.encode_sensor_reply(Rbas.TEMPERATURE, 0, 38125)),
        cl.Payload(3, cl.FmcwConfig(24_025_000, 24_225_000, 0, 7).encode()),
        cl.Payload(1, cl.encode_frame(42, i, q)),
        cl.Payload(2, bytes([0xDB, 0xE0, 0x5A, 0x5B])),  # marker and start bytes inside a payload
        cl.Status(1, 0),
        cl.Status(1, 0x0004),
        cl.Status(0, 0xFFFF),
        cl.Status(3, 0x5A5B),
    ]


CORPUS = _corpus()


def _ids(m):
    return f"{type(m).__name__}-ep{m.endpoint}-{m.data[0] if isinstance(m, cl.Payload) else m.code:x}-{len(m.encode())}"


@pytest.mark.parametrize("msg", CORPUS, ids=_ids)
def test_message_whole(msg):
    d = cl.Decoder()
    assert d.feed(msg.encode()) == [msg]
    assert d.buffered == 0 and d.discarded == 0


@pytest.mark.parametrize("msg", CORPUS, ids=_ids)
def test_message_split_at_every_position(msg):
    wire = msg.encode()
    for k in range(len(wire) + 1):
        d = cl.Decoder()
        out = d.feed(wire[:k]) + d.feed(wire[k:])
        assert out == [msg], k


@pytest.mark.parametrize("msg", CORPUS, ids=_ids)
def test_message_byte_by_byte(msg):
    d = cl.Decoder()
    out = []
    for b in msg.encode():
        out += d.feed(bytes([b]))
    assert out == [msg] and d.discarded == 0


def _garbage(n: int, seed: int) -> bytes:
    """Line noise without start bytes: a decoder must skip it and find the message."""
    g = np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8)
    g[(g == cl.PAYLOAD_START) | (g == cl.STATUS_START)] = 0x00
    return g.tobytes()


@pytest.mark.parametrize("msg", CORPUS, ids=_ids)
def test_message_wrapped_in_garbage(msg):
    pre, post = _garbage(37, 1), _garbage(11, 2)
    d = cl.Decoder()
    assert d.feed(pre + msg.encode() + post) == [msg]
    assert d.discarded == len(pre) + len(post)


@pytest.mark.parametrize("msg", CORPUS, ids=_ids)
def test_message_after_false_starts(msg):
    """A start byte with a bad tail is skipped at once; one with a long length is dropped by flush()."""
    bad_tail = bytes.fromhex("5A01020011 22 3344")  # length 2, tail 33 44 instead of DB E0
    d = cl.Decoder()
    assert d.feed(bad_tail + msg.encode()) == [msg]
    long_start = bytes.fromhex("5A01FF0F")  # claims 4095 payload bytes that never come
    d = cl.Decoder()
    out = d.feed(long_start + msg.encode())
    if len(msg.encode()) < 4095 + 6 - 4:
        assert out == [] and d.buffered > 0
        out += d.flush()
    assert out == [msg]
    assert d.buffered == 0


def test_stream_of_all_messages_in_random_chunks():
    wire = b"".join(_garbage(5, k) + m.encode() for k, m in enumerate(CORPUS))
    rng = np.random.default_rng(11)
    cuts = np.sort(rng.integers(0, len(wire), 60))
    d = cl.Decoder()
    out = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(wire)]):
        out += d.feed(wire[a:b])
    assert out == CORPUS


def test_plausibility_limits_reject_false_headers():
    d = cl.Decoder(max_payload=100, max_endpoint=7)
    msg = cl.Payload(1, b"\x37\x00\x00\x00\x00")
    out = d.feed(bytes.fromhex("5A09050000") + bytes.fromhex("5B09") + bytes.fromhex("5A01FFFF") + msg.encode())
    assert out == [msg]


def test_device_view_ignores_status_start_bytes():
    d = cl.Decoder(accept_status=False)
    msg = cl.Payload(1, bytes([Rbas.GET_FRAME_DATA, 1]))
    assert d.feed(cl.encode_status(1, 0) + msg.encode()) == [msg]


# --- property-based fuzzing ---------------------------------------------------------------------------

DECLARED = (ProtocolError,)
PARSERS = [
    cl.parse_frame,
    cl.parse_frame_header,
    cl.parse_endpoint_list,
    cl.FirmwareInfo.parse,
    cl.DeviceInfo.parse,
    cl.FrameFormat.parse,
    cl.FmcwConfig.parse,
    lambda d: cl.parse_u32_reply(d, Rbas.MIN_INTERVAL, "min interval"),
    lambda d: cl.parse_sensor_reply(d, Rbas.TEMPERATURE, "temperature"),
]


@settings(max_examples=300, deadline=None)
@given(chunks=st.lists(st.binary(max_size=64), max_size=20), flush=st.booleans())
def test_fuzz_decoder_and_parsers_raise_only_declared_errors(chunks, flush):
    d = cl.Decoder(max_payload=4096)
    msgs = []
    for c in chunks:
        msgs += d.feed(c)
    if flush:
        msgs += d.flush()
        assert d.buffered == 0
    total = sum(len(c) for c in chunks)
    assert d.discarded + d.buffered + sum(len(m.encode()) for m in msgs) == total  # every byte accounted for
    for m in msgs:
        if isinstance(m, cl.Payload):
            assert 1 <= len(m.data) <= 4096
            for parse in PARSERS:
                try:
                    parse(m.data)
                except DECLARED:
                    pass
        else:
            try:
                m.error()
            except DECLARED:
                pass


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=80))
def test_fuzz_parsers_on_arbitrary_payloads(data):
    for parse in PARSERS:
        try:
            parse(data)
        except DECLARED:
            pass


message = st.one_of(
    st.builds(cl.Payload, st.integers(0, 255), st.binary(min_size=1, max_size=300)),
    st.builds(cl.Status, st.integers(0, 255), st.integers(0, 0xFFFF)),
)


@settings(max_examples=200, deadline=None)
@given(msgs=st.lists(message, min_size=1, max_size=8), cuts=st.lists(st.integers(0, 5000), max_size=10))
def test_fuzz_any_chunking_of_valid_messages_round_trips(msgs, cuts):
    wire = b"".join(m.encode() for m in msgs)
    edges = sorted({c % (len(wire) + 1) for c in cuts})
    d = cl.Decoder()
    out = []
    for a, b in zip([0, *edges], [*edges, len(wire)]):
        out += d.feed(wire[a:b])
    assert out == msgs and d.discarded == 0
