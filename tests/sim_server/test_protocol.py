"""The simulated KR C4 against the C3 Bridge spec's byte vectors and message layouts, over real sockets."""

from __future__ import annotations

import struct

from rgse_daemon.link import frames as fr
from simulators.krc4.server import HANDLED_TYPES, PROXY_TYPE, KrcServer
from simulators.krc4.variables import Kind

from .conftest import RawClient


def hx(text: str) -> bytes:
    return bytes.fromhex(text)


async def test_spec_vector_read_accu_state(client: RawClient) -> None:
    rsp = await client.raw(hx("01 00 00 0E 00 00 0B 24 41 43 43 55 5F 53 54 41 54 45"))
    assert rsp == hx("01 00 00 10 00 00 0A 23 43 48 41 52 47 45 5F 4F 4B 00 01 01")


async def test_spec_vector_write_ov_pro(server: KrcServer, client: RawClient) -> None:
    rsp = await client.raw(hx("01 00 00 0E 01 00 07 24 4F 56 5F 50 52 4F 00 02 33 35"))
    assert rsp == hx("01 00 00 08 01 00 02 33 35 00 01 01")
    assert server.store.read("$OV_PRO") == "35"


async def test_spec_vector_read_multiple_ping_and_proxy_port(server: KrcServer, client: RawClient) -> None:
    req = hx(
        "04 00 00 24 06 02 00 04 50 00 49 00 4E 00 47 00 00 0B 40 00 50 00 52 00"
        "4F 00 58 00 59 00 5F 00 50 00 4F 00 52 00 54 00"
    )
    spec = hx(
        "04 00 00 1B 06 02 01 00 04 50 00 4F 00 4E 00 47 00 01 00 04 37 00 30 00"
        "30 00 30 00 00 01 01"
    )
    # The spec's server listened on 7000; ours on a free port: substitute the port text and fix the length.
    port_text = str(server.port).encode("utf-16-le")
    spec_port = "7000".encode("utf-16-le")
    body = spec[4:].replace(struct.pack(">H", 4) + spec_port, struct.pack(">H", len(port_text) // 2) + port_text)
    expected = spec[:2] + struct.pack(">H", len(body)) + body
    assert await client.raw(req) == expected


async def test_spec_vector_reset_submit_interpreter(client: RawClient) -> None:
    assert await client.raw(hx("02 8C 00 04 0A 01 00 00")) == hx("02 8C 00 05 0A 01 00 01 01")


async def test_spec_vector_full_name(share, client: RawClient) -> None:
    (share / "R1" / "PROGRAM" / "TEST.SRC").write_text("DEF TEST()\nEND\n")
    req = hx("00 01 00 1B 1B 00 0C 2F 00 52 00 31 00 2F 00 54 00 45 00 53 00 54 00 2E 00 53 00 52 00 43 00")
    rsp = hx(
        "00 01 00 36 1B 00 18 4B 00 52 00 43 00 3A 00 5C 00 52 00 31 00 5C 00 50 00 52 00 4F 00"
        "47 00 52 00 41 00 4D 00 5C 00 54 00 45 00 53 00 54 00 2E 00 53 00 52 00 43 00 00 01 01"
    )
    assert await client.raw(req) == rsp


async def test_internal_variables_answer_over_0_4_and_6(server: KrcServer, client: RawClient) -> None:
    assert await client.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
    assert await client.call(fr.ReadVar("@PROXY_TYPE")) == fr.ReadVarReply(PROXY_TYPE)
    version = await client.call(fr.ReadVarAscii("@PROXY_VERSION"))
    assert version == fr.ReadVarAsciiReply("1.4 (OPEN SOURCE)")
    multi = await client.call(fr.ReadMulti(("@PROXY_HOSTNAME", "@PROXY_ADDRESS", "@PROXY_ENABLED", "@PROXY_TIME")))
    assert isinstance(multi, fr.ReadMultiReply) and multi.ok
    host, addr, enabled, utc = (e.value for e in multi.entries)
    assert (host, addr, enabled) == ("KRC4-SIM", "127.0.0.1", "TRUE")
    assert len(utc) == 20 and utc[10] == "T" and utc.endswith("Z")
    features = await client.call(fr.ReadVarAscii("@PROXY_FEATURES"))
    assert isinstance(features, fr.ReadVarAsciiReply)
    bits = features.value
    assert len(bits) >= 8 and bits[0] == "1" and set(bits) <= {"0", "1"}
    assert {i for i, c in enumerate(reversed(bits)) if c == "1"} == set(HANDLED_TYPES)  # last char is #0


async def test_proxy_info_and_features(client: RawClient) -> None:
    info = await client.call(fr.ProxyInfo())
    assert isinstance(info, fr.ProxyInfoReply) and info.ok
    assert (info.major, info.minor, info.build_type, info.computer_name) == (1, 4, 0, "KRC4-SIM")
    year, month, weekday, day, hour, minute, second, ms = info.utc
    assert year >= 2024 and 1 <= month <= 12 and 0 <= weekday <= 6 and 1 <= day <= 31
    assert hour < 24 and minute < 60 and second < 61 and ms < 1000
    features = await client.call(fr.ProxyFeatures())
    assert isinstance(features, fr.ProxyFeaturesReply)
    assert features.types == HANDLED_TYPES
    assert {0, 1, 4, 5, 6, 7, 10, 11, 12, 13, 14, 17, *range(20, 31), 63} == features.types  # [src]


async def test_failed_reads_and_writes_follow_the_real_server(server: KrcServer, client: RawClient) -> None:
    assert await client.call(fr.ReadVarAscii("RGSE_UNKNOWN")) == fr.ReadVarAsciiReply("", code=0, success=False)
    assert await client.call(fr.WriteVarAscii("$MODE_OP", "#AUT")) == fr.WriteVarAsciiReply("", code=0, success=False)
    assert await client.call(fr.WriteVar("$MODE_OP", "#AUT")) == fr.WriteVarReply("", code=2, success=False)
    assert await client.call(fr.WriteVar("$OV_PRO", "250")) == fr.WriteVarReply("", code=3, success=False)
    assert await client.call(fr.ReadVar("RGSE_UNKNOWN")) == fr.ReadVarReply("", code=0, success=False)
    assert server.store.read("$MODE_OP") == "#T1"


async def test_read_multiple_reports_each_entry(server: KrcServer, client: RawClient) -> None:
    rsp = await client.call(fr.ReadMulti(("$MODE_OP", "NOPE", "$TRACE.STATE")))
    assert rsp == fr.ReadMultiReply(
        (fr.MultiEntry(1, "#T1"), fr.MultiEntry(0, ""), fr.MultiEntry(1, "#T_END")), code=0, success=False
    )
    names = tuple(f"$TORQUE_AXIS_ACT[{i}]" for i in range(1, 7)) * 40
    rsp = await client.call(fr.ReadMulti(names))
    assert isinstance(rsp, fr.ReadMultiReply) and rsp.ok and len(rsp.entries) == 240


async def test_read_multiple_too_long_is_code_10(server: KrcServer, client: RawClient) -> None:
    for i in range(3):
        server.store.declare_global(f"RGSE_LONG{i}", Kind.CHAR, '"' + "x" * 12000 + '"')
    rsp = await client.call(fr.ReadMulti(tuple(f"RGSE_LONG{i}" for i in range(3))))
    assert rsp == fr.ReadMultiReply((), code=10, success=False)


async def test_write_multiple_echoes_the_request_text(server: KrcServer, client: RawClient) -> None:
    server.store.declare_global("RGSE_SPEED", Kind.REAL, "0.0")
    rsp = await client.call(fr.WriteMulti((("$OV_PRO", "50"), ("rgse_speed", "2"), ("$MODE_OP", "#AUT"))))
    assert rsp == fr.WriteMultiReply(  # [src] the request's text, not the controller's "2.0"
        (fr.MultiEntry(1, "50"), fr.MultiEntry(1, "2"), fr.MultiEntry(2, "#AUT")), code=0, success=False
    )
    assert server.store.read("RGSE_SPEED") == "2.0"


async def test_program_control_drives_the_state_machine(server: KrcServer, client: RawClient, share) -> None:
    (share / "R1" / "PROGRAM" / "RGSE_MASS.SRC").write_text("DEF RGSE_MASS()\nEND\n")
    state = lambda: server.store.read("$PRO_STATE1")  # noqa: E731
    select = fr.ProgramControl(fr.ProgCmd.SELECT, 1, "KRC:\\R1\\PROGRAM\\RGSE_MASS.SRC", "", False)
    assert await client.call(fr.ProgramControl(fr.ProgCmd.START, 1)) == fr.ProgramControlReply(
        2, code=6, success=False
    )
    missing = fr.ProgramControl(fr.ProgCmd.SELECT, 1, "KRC:\\R1\\PROGRAM\\NOPE.SRC", "", False)
    assert await client.call(missing) == fr.ProgramControlReply(5, code=3, success=False)
    assert await client.call(select) == fr.ProgramControlReply(5)
    assert (state(), server.store.read("$PRO_NAME1[]")) == ("#P_RESET", '"RGSE_MASS"')
    assert await client.call(fr.ProgramControl(fr.ProgCmd.START, 1)) == fr.ProgramControlReply(2)
    assert state() == "#P_ACTIVE"
    assert (await client.call(fr.ProgramControl(fr.ProgCmd.CANCEL, 1))).ok is False
    assert await client.call(fr.ProgramControl(fr.ProgCmd.STOP, 1)) == fr.ProgramControlReply(3)
    assert state() == "#P_STOP"
    assert await client.call(fr.ProgramControl(fr.ProgCmd.RESET, 1)) == fr.ProgramControlReply(1)
    assert state() == "#P_RESET"
    assert await client.call(fr.ProgramControl(fr.ProgCmd.CANCEL, 1)) == fr.ProgramControlReply(4)
    assert state() == "#P_FREE"
    run = fr.ProgramControl(fr.ProgCmd.RUN, 1, "/R1/RGSE_MASS.SRC", "", True)
    assert await client.call(run) == fr.ProgramControlReply(6)
    assert state() == "#P_ACTIVE"
    assert await client.call(fr.ProgramControl(9, 1)) == fr.ProgramControlReply(9, code=7, success=False)


async def test_benchmark_caps_count_at_10(server: KrcServer, client: RawClient) -> None:
    names = tuple(f"$MOT_TEMP[{1 + i % 6}]" for i in range(12))
    rsp = await client.call(fr.Benchmark(False, 50, names))
    assert isinstance(rsp, fr.BenchmarkReply) and rsp.ok
    assert (rsp.write, rsp.count, rsp.iterations) == (False, 10, 50)
    assert rsp.diff_ms == (rsp.stop_ms - rsp.start_ms) & 0xFFFFFFFF
    rsp = await client.call(fr.Benchmark(True, 3, ("$OV_PRO",), ("42",)))
    assert isinstance(rsp, fr.BenchmarkReply) and (rsp.write, rsp.count) == (True, 1)
    assert server.store.read("$OV_PRO") == "42"


async def test_confirm_all_clears_the_stop_message(server: KrcServer, client: RawClient) -> None:
    server.store.update("$STOPMESS", "TRUE")
    assert await client.call(fr.ConfirmAll()) == fr.ConfirmAllReply()
    assert server.store.read("$STOPMESS") == "FALSE"


async def test_unknown_type_closes_the_connection_without_reply(server: KrcServer) -> None:
    for frame in (hx("00 01 00 01 02"), hx("00 01 00 01 63"), hx("00 01 00 03 08 01 00")):
        c = await RawClient.open(server.port)
        await c.send(frame)
        assert await c.at_eof()
        await c.close()
    assert server.counters.bad_frame_closes == 3


async def test_length_zero_closes_the_connection(server: KrcServer, client: RawClient) -> None:
    await client.send(hx("00 01 00 00 00"))
    assert await client.at_eof()


async def test_malformed_read_is_code_0_with_an_empty_value(server: KrcServer, client: RawClient) -> None:
    rsp = await client.raw(hx("00 05 00 03 00 00 09"))  # #0 announcing a 9-byte name it does not carry
    assert rsp == hx("00 05 00 06 00 00 00 00 00 00")
    assert await client.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")  # connection still usable
    assert server.counters.malformed_requests == 1


async def test_counters_by_type(server: KrcServer, client: RawClient) -> None:
    await client.call(fr.ReadVarAscii("PING"))
    await client.call(fr.ReadVarAscii("PING"))
    await client.call(fr.ReadMulti(("PING",)))
    assert server.counters.requests == 3
    assert server.counters.by_type == {0: 2, 6: 1}
    assert server.counters.connections_accepted == 1
