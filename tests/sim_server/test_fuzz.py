"""Whatever bytes a client sends, the server answers with whole frames or closes that connection, and keeps serving."""

from __future__ import annotations

import asyncio
import struct

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rgse_daemon.link import frames as fr
from simulators.krc4.server import HANDLED_TYPES, KrcServer, ServerConfig

from .conftest import DEADLINE_S, RawClient


def _frames_of_known_types() -> st.SearchStrategy[bytes]:
    """A header of a handled type with a random payload: exercises every decoder's error paths."""
    return st.builds(
        lambda tag, msg_type, payload: struct.pack(">HHB", tag, 1 + len(payload), msg_type) + payload,
        st.integers(0, 0xFFFF),
        st.sampled_from(sorted(HANDLED_TYPES)),
        st.binary(max_size=64),
    )


_CONFIG = dict(latency_s=0.0, benchmark_max_iterations=10, max_file_buffer_bytes=1 << 16)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(min_size=1, max_size=96))
async def test_random_bytes_never_break_the_server(share, data: bytes) -> None:
    async with KrcServer(ServerConfig(**_CONFIG), share) as srv:
        c = await RawClient.open(srv.port)
        try:
            await c.send(data)
            c.writer.write_eof()  # the server closes on EOF, as the real one does
            async with asyncio.timeout(DEADLINE_S):
                answer = await c.reader.read()
        finally:
            await c.close()
        if answer:  # only whole, decodable reply frames ever come back
            frames = fr.FrameReader(responses=True).feed(answer)
            assert b"".join(frames) == answer
            for frame in frames:
                fr.decode_response(frame)
        await _still_serving(srv)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frame=_frames_of_known_types())
async def test_every_whole_frame_of_a_handled_type_gets_one_reply(share, frame: bytes) -> None:
    async with KrcServer(ServerConfig(**_CONFIG), share) as srv:
        c = await RawClient.open(srv.port)
        try:
            raw = await c.raw(frame)
        finally:
            await c.close()
        if frame[4] in (11, 12):  # motion / KCP keys: refused, the subtype echoed (frames has no layout for them)
            assert raw[:2] == frame[:2] and raw[4] == frame[4] and raw[-1] == 0
            await _still_serving(srv)
            return
        tag, rsp = fr.decode_response(raw)
        assert tag == struct.unpack(">H", frame[:2])[0]
        msg_type = rsp.msg_type if isinstance(rsp, fr.FailureReply) else rsp.TYPE
        assert msg_type == frame[4]
        assert rsp.ok or rsp.code != fr.ErrorCode.SUCCESS
        await _still_serving(srv)


async def _still_serving(srv: KrcServer) -> None:
    probe = await RawClient.open(srv.port)
    try:
        assert await probe.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
    finally:
        await probe.close()
