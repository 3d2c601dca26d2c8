"""The C3 Bridge frame codec: spec vectors byte for byte, round trips of every kind, fuzzed decoders and splitter."""

from __future__ import annotations

import asyncio

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgse_daemon.errors import LinkClosed, ProtocolError
from rgse_daemon.link import frames as f


def h(text: str) -> bytes:
    return bytes.fromhex(text.replace("\n", " "))


# --- docs/protocol.md §4 vectors ----------------------------------------------------------------------------------
REQUEST_VECTORS = [
    (0x0100, f.ReadVarAscii("$ACCU_STATE"), "01 00 00 0E 00 00 0B 24 41 43 43 55 5F 53 54 41 54 45"),
    (0x0100, f.WriteVarAscii("$OV_PRO", "35"), "01 00 00 0E 01 00 07 24 4F 56 5F 50 52 4F 00 02 33 35"),
    (
        0x0400,
        f.ReadMulti(("PING", "@PROXY_PORT")),
        "04 00 00 24 06 02 00 04 50 00 49 00 4E 00 47 00 00 0B 40 00 50 00 52 00"
        " 4F 00 58 00 59 00 5F 00 50 00 4F 00 52 00 54 00",
    ),
    (0x028C, f.ProgramControl(f.ProgCmd.RESET, f.Interpreter.SUBMIT), "02 8C 00 04 0A 01 00 00"),
    (
        0x0001,
        f.GetFullName("/R1/TEST.SRC"),
        "00 01 00 1B 1B 00 0C 2F 00 52 00 31 00 2F 00 54 00 45 00 53 00 54 00 2E 00 53 00 52 00 43 00",
    ),
    (0x0003, f.ReadContentData(0), "00 03 00 0A 1E 02 00 00 00 00 FF FF FF FF"),
]

RESPONSE_VECTORS = [
    (0x0100, f.ReadVarAsciiReply("#CHARGE_OK"), "01 00 00 10 00 00 0A 23 43 48 41 52 47 45 5F 4F 4B 00 01 01"),
    (0x0100, f.WriteVarAsciiReply("35"), "01 00 00 08 01 00 02 33 35 00 01 01"),
    (
        0x0400,
        f.ReadMultiReply((f.MultiEntry(1, "PONG"), f.MultiEntry(1, "7000"))),
        "04 00 00 1B 06 02 01 00 04 50 00 4F 00 4E 00 47 00 01 00 04 37 00 30 00 30 00 30 00 00 01 01",
    ),
    (0x028C, f.ProgramControlReply(f.ProgCmd.RESET), "02 8C 00 05 0A 01 00 01 01"),
    (
        0x0001,
        f.GetFullNameReply("KRC:\\R1\\PROGRAM\\TEST.SRC"),
        "00 01 00 36 1B 00 18 4B 00 52 00 43 00 3A 00 5C 00 52 00 31 00 5C 00 50 00 52 00 4F 00"
        " 47 00 52 00 41 00 4D 00 5C 00 54 00 45 00 53 00 54 00 2E 00 53 00 52 00 43 00 00 01 01",
    ),
    (0x0002, f.ReadContentBeginReply(1234), "00 02 00 09 1E 01 00 00 04 D2 00 01 01"),
]


@pytest.mark.parametrize(("tag", "msg", "hexstr"), REQUEST_VECTORS)
def test_request_vectors(tag: int, msg: f.Request, hexstr: str) -> None:
    assert f.encode_request(tag, msg) == h(hexstr)
    assert f.decode_request(h(hexstr)) == (tag, msg)


@pytest.mark.parametrize(("tag", "msg", "hexstr"), RESPONSE_VECTORS)
def test_response_vectors(tag: int, msg: f.Reply, hexstr: str) -> None:
    assert f.encode_response(tag, msg) == h(hexstr)
    assert f.decode_response(h(hexstr)) == (tag, msg)


def test_failed_read_reply_is_typed_with_footer() -> None:
    # #0 failure: LVV = 0, code 0, success 0
    tag, rsp = f.decode_response(h("00 07 00 06 00 00 00 00 00 00"))
    assert tag == 7
    assert rsp == f.ReadVarAsciiReply("", code=0, success=False)
    assert not rsp.ok


def test_kvp_ascii_reply_sized_from_value_length_not_header() -> None:
    good = h("01 00 00 10 00 00 0A 23 43 48 41 52 47 45 5F 4F 4B 00 01 01")
    for bogus_len in (0x0000, 0x000D, 0x0013, 0xFFFF):
        frame = good[:2] + bogus_len.to_bytes(2, "big") + good[4:]
        assert f.decode_response(frame)[1] == f.ReadVarAsciiReply("#CHARGE_OK")
        assert f.split_frames(bytearray(frame + frame), responses=True) == [frame, frame]


def test_failure_reply_keeps_unknown_payload() -> None:
    frame = h("00 09 00 05 1D 07 00 07 00")  # #29 unknown op 7 → code 7, payload = the op echoed
    tag, rsp = f.decode_response(frame)
    assert rsp == f.FailureReply(29, b"\x07", code=7, success=False)
    assert f.encode_response(tag, rsp) == frame


def test_successful_reply_with_bad_layout_is_protocol_error() -> None:
    with pytest.raises(ProtocolError):
        f.decode_response(h("00 09 00 05 1D 07 00 01 01"))


def test_features_bitmap_layout() -> None:
    frame = f.encode_response(1, f.ProxyFeaturesReply(frozenset({0, 1, 6, 7, 63, 255})))
    bitmap = frame[5:37]
    assert bitmap[31] == 0b1100_0011  # types 7..0 in the last byte, MSB = 7
    assert bitmap[0] == 0b1000_0000  # type 255 is the MSB of the first byte
    assert bitmap[31 - 7] == 0b1000_0000  # type 63
    assert f.decode_response(frame)[1].types == frozenset({0, 1, 6, 7, 63, 255})


def test_read_content_begin_uses_source_layout_u16_name_length() -> None:
    frame = f.encode_request(2, f.ReadContentBegin(0, "AB"))
    # @5 op, @6 INT32 copy flags, @10 UINT16 name length, @12 name
    assert frame[5:] == h("01 00 00 00 00 00 02 41 00 42 00")


def test_properties_reply_name_offsets() -> None:
    rsp = f.GetPropertiesReply(16, 5_000_000_000, 32, 1 << 60, -60, 2, 0, (1 << 64) - 1, 120, 3, "X.SRC")
    frame = f.encode_response(9, rsp)
    assert int.from_bytes(frame[61:63], "big") == 5
    assert frame[63:73] == "X.SRC".encode("utf-16-le")
    assert f.decode_response(frame) == (9, rsp)


@pytest.mark.parametrize(
    "bad",
    [
        f.ReadVarAscii("Ω≠latin1"),
        f.ReadVar("x" * 70000),
        f.ReadMulti(tuple(["A"] * 256)),
        f.WriteContentData(0, b"\0" * 65526),
        f.Benchmark(True, 1, ("A",), ()),
        f.ProgramControl(300),
    ],
)
def test_encoder_rejects_what_does_not_fit(bad: f.Request) -> None:
    with pytest.raises(ProtocolError):
        f.encode_request(1, bad)


@pytest.mark.parametrize(
    ("bad", "field"),
    [
        (f.ReadVar(5), "variable name"),  # type: ignore[arg-type]
        (f.ReadMulti(("A", 3)), r"variable names\[1\]"),  # type: ignore[arg-type]
        (f.WriteMulti((("A",),)), r"items\[0\]"),  # type: ignore[arg-type]
        (f.WriteContentData(0, "text"), "chunk data"),  # type: ignore[arg-type]
        (f.Create(1, 2, True, None), "file name"),  # type: ignore[arg-type]
        (f.SetAttribute(1 << 31, 0, "A"), "attributes"),
        (f.ProgramControl(5, 1.5), "interpreter"),  # type: ignore[arg-type]
    ],
)
def test_encoder_error_names_the_field(bad: f.Request, field: str) -> None:
    with pytest.raises(ProtocolError, match=field):
        f.encode_request(1, bad)


@pytest.mark.parametrize(
    ("decode", "hexstr", "field"),
    [
        (f.decode_request, "00 01 00 0A 06 02 00 01 41 00 00 02 42 00", r"variable names\[1\]"),
        (f.decode_request, "00 01 00 0A 0A 05 00 01 00 01 41 00 00 00", "force"),
        (f.decode_request, "00 01 00 06 1D 07 00 00 00 01", "unknown file operation 7"),
        (f.decode_request, "00 01 00 02 63 00", "unknown request message type 99"),
        (f.decode_response, "00 01 00 0A 06 02 01 00 00 01 00 05 01 01", r"entries\[1\] value"),
        (f.decode_response, "00 01 00 08 1B 00 01 00 D8 00 01 01", "path is not valid UTF-16"),
    ],
)
def test_decoder_error_names_the_field(decode, hexstr: str, field: str) -> None:
    with pytest.raises(ProtocolError, match=field):
        decode(h(hexstr))


# --- #20 #22 #23 #24 #25 #28: layouts of docs/protocol.md §2, computed by hand ---------------------------------
FILE_OP_REQUEST_LAYOUTS = [
    # #20: @5 INT32 attributes, @9 INT32 mask, @13 wstr name
    (1, f.SetAttribute(1, 1, "A"), "00 01 00 0D 14 00 00 00 01 00 00 00 01 00 01 41 00"),
    (1, f.SetAttribute(-1, 0x10000020, "A"), "00 01 00 0D 14 FF FF FF FF 10 00 00 20 00 01 41 00"),
    # #22: @5 UINT16 itemType (Module 32), @7 UINT8 modulePart (SRCDAT 6), @8 BOOL always, wstr name, wstr template
    (2, f.Create(32, 6, False, "AB"), "00 02 00 0D 16 00 20 06 00 00 02 41 00 42 00 00 00"),
    (2, f.Create(256, 0, True, "A", "T"), "00 02 00 0D 16 01 00 00 01 00 01 41 00 00 01 54 00"),
    # #23: @5 BOOL always, @6 wstr name
    (3, f.Delete(True, "AB"), "00 03 00 08 17 01 00 02 41 00 42 00"),
    (3, f.Delete(False, "\u20ac"), "00 03 00 06 17 00 00 01 AC 20"),  # € is one UTF-16 unit, little-endian
    (3, f.Delete(False, "\U0001d11e"), "00 03 00 08 17 00 00 02 34 D8 1E DD"),  # a surrogate pair counts 2 units
    # #24 / #25: @5 INT32 copyFlags, @9 wstr source, wstr destination
    (4, f.Copy(64, "A", "B"), "00 04 00 0D 18 00 00 00 40 00 01 41 00 00 01 42 00"),
    (5, f.Move(0, "A", "B"), "00 05 00 0D 19 00 00 00 00 00 01 41 00 00 01 42 00"),
    # #28: @5 wstr path (the spec's #27 example, reversed)
    (
        1,
        f.GetKrcName("KRC:\\R1\\PROGRAM\\TEST.SRC"),
        "00 01 00 33 1C 00 18 4B 00 52 00 43 00 3A 00 5C 00 52 00 31 00 5C 00 50 00 52 00 4F 00"
        " 47 00 52 00 41 00 4D 00 5C 00 54 00 45 00 53 00 54 00 2E 00 53 00 52 00 43 00",
    ),
]

FILE_OP_RESPONSE_LAYOUTS = [
    # footer-only replies: Message Length 4 = type byte + error code + success
    (1, f.SetAttributeReply(), "00 01 00 04 14 00 01 01"),
    (2, f.CreateReply(), "00 02 00 04 16 00 01 01"),
    (3, f.DeleteReply(), "00 03 00 04 17 00 01 01"),
    (3, f.DeleteReply(code=3, success=False), "00 03 00 04 17 00 03 00"),
    (4, f.CopyReply(code=2, success=False), "00 04 00 04 18 00 02 00"),
    (5, f.MoveReply(), "00 05 00 04 19 00 01 01"),
    (
        1,
        f.GetKrcNameReply("/R1/TEST.SRC"),
        "00 01 00 1E 1C 00 0C 2F 00 52 00 31 00 2F 00 54 00 45 00 53 00 54 00 2E 00 53 00 52 00 43 00 00 01 01",
    ),
    (1, f.GetKrcNameReply("", code=3, success=False), "00 01 00 06 1C 00 00 00 03 00"),
]


@pytest.mark.parametrize(("tag", "msg", "hexstr"), FILE_OP_REQUEST_LAYOUTS)
def test_file_op_request_layouts(tag: int, msg: f.Request, hexstr: str) -> None:
    assert f.encode_request(tag, msg) == h(hexstr)
    assert f.decode_request(h(hexstr)) == (tag, msg)


@pytest.mark.parametrize(("tag", "msg", "hexstr"), FILE_OP_RESPONSE_LAYOUTS)
def test_file_op_response_layouts(tag: int, msg: f.Reply, hexstr: str) -> None:
    assert f.encode_response(tag, msg) == h(hexstr)
    assert f.decode_response(h(hexstr)) == (tag, msg)


def test_create_item_type_is_uint16_on_the_wire() -> None:
    assert f.encode_request(1, f.Create(0xFFFF, 255, True, ""))[5:10] == h("FF FF FF 01 00")
    for bad in (f.Create(0x10000, 0, False, "A"), f.Create(-1, 0, False, "A"), f.Create(1, 256, False, "A")):
        with pytest.raises(ProtocolError):
            f.encode_request(1, bad)
    # an #21-style INT32 item type shifts every later field: not a valid #22
    with pytest.raises(ProtocolError):
        f.decode_request(h("00 01 00 0F 16 00 00 00 20 06 00 00 02 41 00 42 00 00 00"))


def test_footer_only_reply_with_a_payload() -> None:
    with pytest.raises(ProtocolError):  # success with bytes the layout does not have
        f.decode_response(h("00 03 00 05 17 07 00 01 01"))
    tag, rsp = f.decode_response(h("00 03 00 05 17 07 00 03 00"))  # a failure keeps them raw
    assert (tag, rsp) == (3, f.FailureReply(23, b"\x07", code=3, success=False))


def test_largest_write_chunk_fits() -> None:
    frame = f.encode_request(1, f.WriteContentData(0, b"\xaa" * f.MAX_WRITE_CHUNK))
    assert len(frame) == f.MAX_FRAME_SIZE


# --- round trips ------------------------------------------------------------------------------------------------
text = st.text(max_size=40)
latin = st.text(alphabet=st.characters(max_codepoint=255), max_size=40)
u32 = st.integers(0, 2**32 - 1)
i32 = st.integers(-(2**31), 2**31 - 1)
tags = st.integers(0, 0xFFFF)

requests = st.one_of(
    st.builds(f.ReadVarAscii, latin),
    st.builds(f.WriteVarAscii, latin, latin),
    st.builds(f.ReadVar, text),
    st.builds(f.WriteVar, text, text),
    st.builds(f.ReadMulti, st.lists(text, max_size=8).map(tuple)),
    st.builds(f.WriteMulti, st.lists(st.tuples(text, text), max_size=8).map(tuple)),
    st.builds(f.ProgramControl, st.integers(1, 4), st.integers(-(2**15), 2**15 - 1)),
    st.builds(f.ProgramControl, st.integers(5, 6), st.integers(-1, 1), text, text, st.booleans()),
    st.just(f.ProxyInfo()),
    st.just(f.ProxyFeatures()),
    st.builds(f.Benchmark, st.just(False), u32, st.lists(text, max_size=5).map(tuple)),
    st.lists(st.tuples(text, text), max_size=5).flatmap(
        lambda kv: st.builds(
            f.Benchmark, st.just(True), u32, st.just(tuple(k for k, _ in kv)), st.just(tuple(v for _, v in kv))
        )
    ),
    st.builds(f.SetAttribute, i32, i32, text),
    st.builds(f.NameList, i32, i32, text),
    st.builds(f.Create, st.integers(0, 0xFFFF), st.integers(0, 255), st.booleans(), text, text),
    st.builds(f.Delete, st.booleans(), text),
    st.builds(f.Copy, i32, text, text),
    st.builds(f.Move, i32, text, text),
    st.builds(f.GetKrcName, text),
    st.builds(f.GetProperties, i32, text),
    st.builds(f.GetFullName, text),
    st.builds(f.WriteContentBegin, u32),
    st.builds(f.WriteContentData, u32, st.binary(max_size=300)),
    st.just(f.WriteContentGetSize()),
    st.builds(f.WriteContentEnd, i32, text),
    st.builds(f.ReadContentBegin, i32, text),
    st.builds(f.ReadContentData, u32, u32),
    st.just(f.ReadContentGetSize()),
    st.just(f.ReadContentEnd()),
    st.just(f.ConfirmAll()),
)

footer = {"code": st.integers(0, 0xFFFF), "success": st.booleans()}
entries = st.lists(st.builds(f.MultiEntry, st.integers(0, 255), text), max_size=8).map(tuple)
ft = st.integers(0, 2**64 - 1)
replies = st.one_of(
    st.builds(f.ReadVarAsciiReply, latin, **footer),
    st.builds(f.WriteVarAsciiReply, latin, **footer),
    st.builds(f.ReadVarReply, text, **footer),
    st.builds(f.WriteVarReply, text, **footer),
    st.builds(f.ReadMultiReply, entries, **footer),
    st.builds(f.WriteMultiReply, entries, **footer),
    st.builds(f.ProgramControlReply, st.integers(0, 255), **footer),
    st.builds(
        f.ProxyInfoReply,
        st.integers(0, 255),
        st.integers(0, 255),
        st.integers(0, 3),
        st.tuples(*[st.integers(0, 0xFFFF)] * 8),
        text,
        **footer,
    ),
    st.builds(f.ProxyFeaturesReply, st.frozensets(st.integers(0, 255)), **footer),
    st.builds(f.BenchmarkReply, st.booleans(), st.integers(0, 255), u32, u32, u32, u32, **footer),
    st.builds(f.NameListReply, st.lists(text, max_size=5).map(tuple), st.lists(text, max_size=5).map(tuple), **footer),
    st.builds(f.GetPropertiesReply, i32, ft, i32, ft, i32, ft, i32, ft, i32, i32, text, **footer),
    st.builds(f.GetFullNameReply, text, **footer),
    st.builds(f.GetKrcNameReply, text, **footer),
    st.builds(f.SetAttributeReply, **footer),
    st.builds(f.CreateReply, **footer),
    st.builds(f.DeleteReply, **footer),
    st.builds(f.CopyReply, **footer),
    st.builds(f.MoveReply, **footer),
    st.builds(f.WriteContentBeginReply, u32, **footer),
    st.builds(f.WriteContentGetSizeReply, u32, **footer),
    st.builds(f.WriteContentDataReply, u32, u32, **footer),
    st.builds(f.WriteContentEndReply, **footer),
    st.builds(f.ReadContentBeginReply, u32, **footer),
    st.builds(f.ReadContentGetSizeReply, u32, **footer),
    st.builds(f.ReadContentDataReply, u32, st.binary(max_size=300), **footer),
    st.builds(f.ReadContentEndReply, **footer),
    st.builds(f.ConfirmAllReply, **footer),
)


@settings(max_examples=300, deadline=None)
@given(tags, requests)
def test_request_round_trip(tag: int, req: f.Request) -> None:
    frame = f.encode(tag, req)
    assert int.from_bytes(frame[2:4], "big") == len(frame) - 4
    assert f.decode_request(frame) == (tag, req)


@settings(max_examples=300, deadline=None)
@given(tags, replies)
def test_response_round_trip(tag: int, rsp: f.Reply) -> None:
    frame = f.encode(tag, rsp)
    assert int.from_bytes(frame[2:4], "big") == len(frame) - 4
    got_tag, got = f.decode_response(frame)
    assert got_tag == tag
    assert got == rsp
    assert (got.code, got.success) == (rsp.code, rsp.success)


# --- fuzzing ----------------------------------------------------------------------------------------------------
def _decodes_or_protocol_error(fn, data: bytes) -> None:
    try:
        fn(data)
    except ProtocolError:
        pass


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=80))
def test_decoders_on_garbage_only_raise_protocol_error(data: bytes) -> None:
    _decodes_or_protocol_error(f.decode_request, data)
    _decodes_or_protocol_error(f.decode_response, data)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([int(t) for t in f.MsgType]), st.binary(max_size=60), tags)
def test_decoders_on_wellframed_garbage(msg_type: int, payload: bytes, tag: int) -> None:
    frame = tag.to_bytes(2, "big") + (len(payload) + 1).to_bytes(2, "big") + bytes([msg_type]) + payload
    _decodes_or_protocol_error(f.decode_request, frame)
    _decodes_or_protocol_error(f.decode_response, frame)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(tags, replies), min_size=1, max_size=6), st.lists(st.integers(0, 4000), max_size=10))
def test_splitter_reassembles_responses_cut_anywhere(msgs, cuts) -> None:
    frames = [f.encode(t, m) for t, m in msgs]
    stream = b"".join(frames)
    points = sorted({c % (len(stream) + 1) for c in cuts})
    reader = f.FrameReader(responses=True)
    got: list[bytes] = []
    prev = 0
    for p in [*points, len(stream)]:
        got += reader.feed(stream[prev:p])
        prev = p
    assert got == frames
    assert reader.pending == 0
    assert [f.decode_response(x) for x in got] == [(t, m) for t, m in msgs]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(tags, requests), min_size=1, max_size=6), st.integers(1, 50))
def test_splitter_reassembles_requests_in_small_pieces(msgs, step: int) -> None:
    frames = [f.encode(t, m) for t, m in msgs]
    stream = b"".join(frames)
    reader = f.FrameReader(responses=False)
    got: list[bytes] = []
    for i in range(0, len(stream), step):
        got += reader.feed(stream[i : i + step])
    assert got == frames


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200), st.booleans())
def test_splitter_on_garbage(data: bytes, responses: bool) -> None:
    reader = f.FrameReader(responses=responses)
    try:
        out = reader.feed(data)
    except ProtocolError:
        return
    assert sum(map(len, out)) + reader.pending == len(data)


def test_splitter_rejects_zero_and_oversized_length() -> None:
    with pytest.raises(ProtocolError, match="length 0"):
        f.split_frames(bytearray(h("00 01 00 00 06")), responses=True)
    with pytest.raises(ProtocolError, match="exceeds"):
        f.split_frames(bytearray(h("00 01 10 00 06")), responses=False, max_length=1000)


async def test_read_frame_from_stream() -> None:
    stream = asyncio.StreamReader()
    a = f.encode(5, f.ReadVarAsciiReply("PONG"))
    b = f.encode(6, f.ReadMultiReply((f.MultiEntry(1, "x"),)))
    stream.feed_data(a + b + a[:6])
    stream.feed_eof()
    assert await f.read_frame(stream, responses=True) == a
    assert await f.read_frame(stream, responses=True) == b
    with pytest.raises(LinkClosed):
        await f.read_frame(stream, responses=True)
