"""File operations #20–#30 over a real socket against the share directory."""

from __future__ import annotations

import os
from pathlib import Path

from rgse_daemon.link import frames as fr
from simulators.krc4.server import KrcServer

from .conftest import RawClient


async def test_300_kb_round_trip_in_chunks(share: Path, server: KrcServer, client: RawClient) -> None:
    content = os.urandom(300_000)
    assert await client.call(fr.WriteContentBegin(len(content))) == fr.WriteContentBeginReply(len(content))
    for off in range(0, len(content), fr.MAX_WRITE_CHUNK):
        chunk = content[off : off + fr.MAX_WRITE_CHUNK]
        assert await client.call(fr.WriteContentData(off, chunk)) == fr.WriteContentDataReply(off, len(chunk))
    assert await client.call(fr.WriteContentGetSize()) == fr.WriteContentGetSizeReply(len(content))
    assert await client.call(fr.WriteContentEnd(0, "KRC:\\R1\\PROGRAM\\BLOB.DAT")) == fr.WriteContentEndReply()
    assert (share / "R1" / "PROGRAM" / "BLOB.DAT").read_bytes() == content

    assert await client.call(fr.ReadContentBegin(0, "/R1/BLOB.DAT")) == fr.ReadContentBeginReply(len(content))
    got = bytearray()
    while True:
        rsp = await client.call(fr.ReadContentData(len(got)))
        assert isinstance(rsp, fr.ReadContentDataReply) and rsp.ok and rsp.offset == len(got)
        assert len(rsp.data) <= fr.MAX_READ_CHUNK
        if not rsp.data:
            break
        got += rsp.data
    assert bytes(got) == content
    assert await client.call(fr.ReadContentGetSize()) == fr.ReadContentGetSizeReply(len(content))
    assert await client.call(fr.ReadContentEnd()) == fr.ReadContentEndReply()
    assert await client.call(fr.ReadContentGetSize()) == fr.ReadContentGetSizeReply(0)


async def test_buffers_belong_to_one_connection(server: KrcServer, client: RawClient) -> None:
    await client.call(fr.WriteContentBegin(10))
    other = await RawClient.open(server.port)
    try:
        assert await other.call(fr.WriteContentGetSize()) == fr.WriteContentGetSizeReply(0)
        end = await other.call(fr.WriteContentEnd(0, "/TRACE/x.txt"))
        assert end == fr.WriteContentEndReply(code=0, success=False)
    finally:
        await other.close()
    assert await client.call(fr.WriteContentGetSize()) == fr.WriteContentGetSizeReply(10)


async def test_paths_escaping_the_share_are_refused_with_code_3(share: Path, client: RawClient) -> None:
    await client.call(fr.WriteContentBegin(3))
    await client.call(fr.WriteContentData(0, b"bad"))
    for name in ("KRC:\\R1\\..\\..\\evil.txt", "C:\\Windows\\evil.txt", "/TRACE/../../evil.txt"):
        assert await client.call(fr.WriteContentEnd(0, name)) == fr.WriteContentEndReply(code=3, success=False)
        rsp = await client.call(fr.ReadContentBegin(0, name))
        assert rsp == fr.ReadContentBeginReply(0, code=3, success=False)
        assert await client.call(fr.GetFullName(name)) == fr.GetFullNameReply("", code=3, success=False)
    assert not (share.parent / "evil.txt").exists()
    assert await client.call(fr.WriteContentGetSize()) == fr.WriteContentGetSizeReply(3)  # kept after failed End


async def test_name_list_and_properties(share: Path, client: RawClient) -> None:
    trace = share / "TRACE"
    (trace / "m01_NextGenDrive#3.dat").write_text("x")
    (trace / "m01_NextGenDrive#3.r64").write_bytes(b"\0" * 16)
    rsp = await client.call(fr.NameList(0, 0, "C:\\KRC\\ROBOTER\\TRACE\\*.r64"))
    assert isinstance(rsp, fr.NameListReply) and rsp.ok
    assert rsp.items == ("C:\\KRC\\ROBOTER\\TRACE\\m01_NextGenDrive#3.r64",)
    assert rsp.infos[0].split(";")[1] == "16"
    props = await client.call(fr.GetProperties(255, "/TRACE/m01_NextGenDrive#3.r64"))
    assert isinstance(props, fr.GetPropertiesReply) and props.ok
    assert props.size_bytes == 16 and props.name == "C:\\KRC\\ROBOTER\\TRACE\\m01_NextGenDrive#3.r64"
    mtime_ns = (trace / "m01_NextGenDrive#3.r64").stat().st_mtime_ns
    assert props.modified_filetime == mtime_ns // 100 + 116_444_736_000_000_000
    missing = await client.call(fr.GetProperties(255, "/TRACE/none.r64"))
    assert missing == fr.GetPropertiesReply(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, "", code=3, success=False)
    assert await client.call(fr.NameList(0, 0, "/NOPE")) == fr.NameListReply((), (), code=3, success=False)


async def test_read_data_without_begin_fails(client: RawClient) -> None:
    rsp = await client.call(fr.ReadContentData(0))
    assert rsp == fr.ReadContentDataReply(0, b"", code=0, success=False)


async def test_delete_create_copy_move_over_the_wire(share: Path, client: RawClient) -> None:
    prog = share / "R1" / "PROGRAM"
    assert await client.call(fr.Create(32, 6, False, "KRC:\\R1\\PROGRAM\\NEW.SRC", "")) == fr.CreateReply()
    assert (prog / "NEW.SRC").read_bytes() == b""
    assert await client.call(fr.Create(32, 6, False, "/R1/NEW.SRC", "")) == fr.CreateReply(code=2, success=False)
    (prog / "NEW.SRC").write_text("DEF NEW()\nEND\n")
    assert await client.call(fr.Copy(0, "/R1/NEW.SRC", "/R1/COPY.SRC")) == fr.CopyReply()
    assert await client.call(fr.Copy(0, "/R1/NEW.SRC", "/R1/COPY.SRC")) == fr.CopyReply(code=2, success=False)
    assert await client.call(fr.Copy(64, "/R1/NEW.SRC", "/R1/COPY.SRC")) == fr.CopyReply()
    assert (prog / "COPY.SRC").read_text() == "DEF NEW()\nEND\n"
    assert await client.call(fr.Move(0, "/R1/COPY.SRC", "C:\\KRC\\ROBOTER\\TRACE\\MOVED.SRC")) == fr.MoveReply()
    assert not (prog / "COPY.SRC").exists() and (share / "TRACE" / "MOVED.SRC").exists()
    assert await client.call(fr.Move(0, "/R1/NEW.SRC", "/TRACE/MOVED.SRC")) == fr.MoveReply(code=2, success=False)
    assert await client.call(fr.SetAttribute(1, 1, "/TRACE/MOVED.SRC")) == fr.SetAttributeReply()
    assert await client.call(fr.Delete(False, "/TRACE/MOVED.SRC")) == fr.DeleteReply(code=2, success=False)
    assert await client.call(fr.Delete(True, "/TRACE/MOVED.SRC")) == fr.DeleteReply()
    assert not (share / "TRACE" / "MOVED.SRC").exists()
    assert await client.call(fr.Delete(False, "/TRACE/MOVED.SRC")) == fr.DeleteReply(code=3, success=False)


async def test_new_file_operations_refuse_paths_escaping_the_share(share: Path, client: RawClient) -> None:
    outside = share.parent / "victim.txt"
    outside.write_text("keep")
    (share / "TRACE" / "in.txt").write_text("in")
    for name in ("KRC:\\R1\\..\\..\\victim.txt", "C:\\Windows\\victim.txt", "/TRACE/../../victim.txt"):
        refused = {"code": 3, "success": False}
        assert await client.call(fr.Delete(True, name)) == fr.DeleteReply(**refused)
        assert await client.call(fr.Create(8, 0, True, name, "")) == fr.CreateReply(**refused)
        assert await client.call(fr.SetAttribute(1, 1, name)) == fr.SetAttributeReply(**refused)
        assert await client.call(fr.Copy(64, "/TRACE/in.txt", name)) == fr.CopyReply(**refused)
        assert await client.call(fr.Copy(64, name, "/TRACE/out.txt")) == fr.CopyReply(**refused)
        assert await client.call(fr.Move(64, "/TRACE/in.txt", name)) == fr.MoveReply(**refused)
        assert await client.call(fr.GetKrcName(name)) == fr.GetKrcNameReply("", **refused)
    assert outside.read_text() == "keep" and (share / "TRACE" / "in.txt").read_text() == "in"
    assert not (share / "TRACE" / "out.txt").exists()


async def test_krc_name_and_full_name_are_inverse(share: Path, client: RawClient) -> None:
    assert await client.call(fr.GetKrcName("KRC:\\R1\\PROGRAM\\TEST.SRC")) == fr.GetKrcNameReply("/R1/TEST.SRC")
    assert await client.call(fr.GetFullName("/R1/TEST.SRC")) == fr.GetFullNameReply("KRC:\\R1\\PROGRAM\\TEST.SRC")
    trace = "C:\\KRC\\ROBOTER\\TRACE\\a.dat"
    assert await client.call(fr.GetKrcName(trace)) == fr.GetKrcNameReply("/TRACE/a.dat")
    assert await client.call(fr.GetFullName("/TRACE/a.dat")) == fr.GetFullNameReply(trace)


async def test_malformed_footer_only_request_is_code_9(client: RawClient) -> None:
    frame = bytes.fromhex("00 09 00 04 17 01 00 05")  # #23: always, then a name length of 5 and no name
    assert fr.decode_response(await client.raw(frame)) == (9, fr.DeleteReply(code=9, success=False))
    frame = bytes.fromhex("00 0A 00 02 1C 00")  # #28 cut inside the length field: an empty name in the reply
    assert await client.raw(frame) == bytes.fromhex("00 0A 00 06 1C 00 00 00 09 00")


async def test_refuse_types_fault(server: KrcServer, share: Path, client: RawClient) -> None:
    (share / "TRACE" / "t.dat").write_text("x")
    server.faults.refuse_types = {23: 2, 0: 6}
    assert await client.call(fr.Delete(False, "/TRACE/t.dat")) == fr.DeleteReply(code=2, success=False)
    assert await client.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("", code=6, success=False)
    assert (share / "TRACE" / "t.dat").exists() and server.counters.faults_fired["refuse_types"] == 2
    server.faults.refuse_types.clear()
    assert await client.call(fr.Delete(False, "/TRACE/t.dat")) == fr.DeleteReply()
    assert not (share / "TRACE" / "t.dat").exists()
