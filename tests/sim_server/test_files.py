"""The share directory of the simulated KR C4: name mapping, escape refusal, buffers of #29/#30, #20–#28."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simulators.krc4.files import (
    ATTR_ARCHIVE,
    ATTR_DIRECTORY,
    ATTR_READONLY,
    CODE_ACCESS,
    CODE_ARGUMENT,
    CODE_LONG_ANSWER,
    COPY_OVERWRITE_EXISTS,
    COPY_OVERWRITE_READ,
    ITEM_DIR,
    ITEM_MODULE,
    MAX_CHUNK_BYTES,
    FileOpError,
    FileSession,
    ShareFiles,
    filetime,
)


@pytest.fixture
def share(tmp_path: Path) -> ShareFiles:
    (tmp_path / "R1" / "PROGRAM").mkdir(parents=True)
    (tmp_path / "TRACE").mkdir()
    return ShareFiles(tmp_path)


@pytest.mark.parametrize(
    ("name", "rel"),
    [
        ("KRC:\\R1\\PROGRAM\\TEST.SRC", "R1/PROGRAM/TEST.SRC"),
        ("krc:/r1/program/test.src", "R1/PROGRAM/test.src"),
        ("/R1/TEST.SRC", "R1/PROGRAM/TEST.SRC"),
        ("/R1/PROGRAM/TEST.SRC", "R1/PROGRAM/TEST.SRC"),
        ("/R1/PROGRAM", "R1/PROGRAM"),
        ("C:\\KRC\\ROBOTER\\TRACE\\t1.dat", "TRACE/t1.dat"),
        ("c:/krc/roboter/trace/t1.dat", "TRACE/t1.dat"),
        ("/TRACE/t1.dat", "TRACE/t1.dat"),
    ],
)
def test_names_map_below_the_share(share: ShareFiles, name: str, rel: str) -> None:
    assert share.resolve(name) == share.root / rel


def test_existing_entries_match_case_insensitively(share: ShareFiles) -> None:
    (share.root / "R1" / "PROGRAM" / "Mass.src").write_text("DEF Mass()\nEND\n")
    assert share.resolve("KRC:\\R1\\PROGRAM\\MASS.SRC").name == "Mass.src"
    assert share.full_name("/r1/mass.SRC") == "KRC:\\R1\\PROGRAM\\Mass.src"


def test_full_name_and_krc_name_follow_the_spec_example(share: ShareFiles) -> None:
    assert share.full_name("/R1/TEST.SRC") == "KRC:\\R1\\PROGRAM\\TEST.SRC"
    assert share.krc_name("KRC:\\R1\\PROGRAM\\TEST.SRC") == "/R1/TEST.SRC"
    assert share.full_name("/TRACE/a.dat") == "C:\\KRC\\ROBOTER\\TRACE\\a.dat"


@pytest.mark.parametrize(
    "name",
    [
        "KRC:\\R1\\..\\..\\etc\\passwd",
        "/R1/../../x",
        "C:\\KRC\\ROBOTER\\..\\x",
        "C:\\Windows\\system.ini",
        "D:\\x",
        "\\\\server\\share\\x",
        "//server/x",
        "relative\\x",
        "KRC:\\R1\\C:x",
        "",
        "KRC:\\a\x00b",
    ],
)
def test_names_leaving_the_share_are_refused_with_code_3(share: ShareFiles, name: str) -> None:
    with pytest.raises(FileOpError) as err:
        share.resolve(name)
    assert err.value.code == CODE_ARGUMENT


def test_a_symlink_out_of_the_share_is_refused(share: ShareFiles, tmp_path_factory: pytest.TempPathFactory) -> None:
    outside = tmp_path_factory.mktemp("outside")
    (outside / "secret").write_text("x")
    (share.root / "TRACE" / "link").symlink_to(outside)
    with pytest.raises(FileOpError) as err:
        share.resolve("/TRACE/link/secret")
    assert err.value.code == CODE_ARGUMENT


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.sampled_from(["..", ".", "R1", "x", "TRACE", "PROGRAM", "a.src"]), max_size=8),
    st.sampled_from(["KRC:\\", "/", "C:\\KRC\\ROBOTER\\", "KRC:/"]),
    st.sampled_from(["\\", "/"]),
)
def test_no_name_ever_resolves_outside_the_share(tmp_path_factory, parts, prefix, sep) -> None:
    root = tmp_path_factory.mktemp("share")
    share = ShareFiles(root)
    try:
        path = share.resolve(prefix + sep.join(parts))
    except FileOpError as exc:
        assert exc.code == CODE_ARGUMENT
        assert ".." in parts or "." in parts
        return
    real = path.resolve()
    assert real == share.root or share.root in real.parents


def test_write_buffer_round_trip_of_300_kb_in_chunks(share: ShareFiles) -> None:
    content = os.urandom(300_000)
    session = FileSession(share)
    assert session.write_size() == 0
    assert session.write_begin(len(content)) == len(content)
    chunk = 65_525
    for off in range(0, len(content), chunk):
        assert session.write_data(off, content[off : off + chunk]) == len(content[off : off + chunk])
    assert session.write_size() == len(content)
    session.write_end("KRC:\\R1\\PROGRAM\\BIG.DAT")
    assert (share.root / "R1" / "PROGRAM" / "BIG.DAT").read_bytes() == content
    assert session.write_size() == 0  # freed after a successful End
    assert not [p for p in (share.root / "R1" / "PROGRAM").iterdir() if p.name.endswith(".part")]

    reader = FileSession(share)
    assert reader.read_begin("/R1/BIG.DAT") == len(content)
    got = bytearray()
    while chunk_bytes := reader.read_data(len(got), 0xFFFFFFFF):
        assert len(chunk_bytes) <= MAX_CHUNK_BYTES
        got += chunk_bytes
    assert bytes(got) == content
    reader.read_end()
    assert reader.read_size() == 0


def test_write_data_is_clipped_at_the_buffer_end(share: ShareFiles) -> None:
    session = FileSession(share)
    session.write_begin(10)
    assert session.write_data(8, b"abcd") == 2
    assert session.write_data(10, b"x") == 0
    assert session.write_data(0, b"") == 0
    session.write_end("/TRACE/clip.bin")
    assert (share.root / "TRACE" / "clip.bin").read_bytes() == b"\0" * 8 + b"ab"


def test_write_without_begin_and_oversized_begin_fail_typed(share: ShareFiles) -> None:
    session = FileSession(share, max_buffer_bytes=100)
    with pytest.raises(FileOpError):
        session.write_data(0, b"x")
    with pytest.raises(FileOpError) as err:
        session.write_begin(101)
    assert err.value.code == 4
    with pytest.raises(FileOpError):
        session.write_end("/TRACE/x")


def test_failed_end_keeps_the_buffer_and_the_old_file(share: ShareFiles) -> None:
    target = share.root / "TRACE" / "ro.txt"
    target.write_text("original")
    target.chmod(0o444)
    session = FileSession(share)
    session.write_begin(3)
    session.write_data(0, b"new")
    with pytest.raises(FileOpError):
        session.write_end("/TRACE/ro.txt")
    assert session.write_size() == 3
    assert target.read_text() == "original"


def test_properties_report_filetime_and_attributes(share: ShareFiles) -> None:
    path = share.root / "R1" / "PROGRAM" / "A.SRC"
    path.write_text("DEF A()\nEND\n")
    os.utime(path, ns=(1_700_000_000_000_000_000, 1_700_000_000_000_000_000))
    props = share.properties("/R1/A.SRC")
    assert props.size_bytes == path.stat().st_size
    assert props.item_type & ITEM_MODULE
    assert props.attributes == ATTR_ARCHIVE
    assert props.modified_ft == 1_700_000_000_000_000_000 // 100 + 116_444_736_000_000_000
    assert share.properties("KRC:\\R1\\PROGRAM").attributes == ATTR_DIRECTORY
    share.set_attribute("/R1/A.SRC", ATTR_READONLY, ATTR_READONLY)
    assert share.properties("/R1/A.SRC").attributes & ATTR_READONLY
    with pytest.raises(FileOpError) as err:
        share.properties("/R1/NOPE.SRC")
    assert err.value.code == CODE_ARGUMENT


def test_filetime_epoch() -> None:
    assert filetime(0) == 116_444_736_000_000_000


def test_name_list_masks_types_and_recursion(share: ShareFiles) -> None:
    prog = share.root / "R1" / "PROGRAM"
    for n in ("A.SRC", "A.DAT", "notes.txt"):
        (prog / n).write_text("x")
    (prog / "SUB").mkdir()
    (prog / "SUB" / "B.SRC").write_text("x")
    items, infos = share.name_list("KRC:\\R1\\PROGRAM")
    assert items == [
        "KRC:\\R1\\PROGRAM\\A.DAT",
        "KRC:\\R1\\PROGRAM\\A.SRC",
        "KRC:\\R1\\PROGRAM\\notes.txt",
        "KRC:\\R1\\PROGRAM\\SUB\\",
    ]
    assert len(infos) == 4 and infos[0].split(";")[1] == "1"
    items, _ = share.name_list("KRC:\\R1\\PROGRAM\\*.src")
    assert items == ["KRC:\\R1\\PROGRAM\\A.SRC"]
    items, _ = share.name_list("KRC:\\R1\\PROGRAM", item_type=ITEM_DIR)
    assert items == ["KRC:\\R1\\PROGRAM\\SUB\\"]
    items, _ = share.name_list("KRC:\\R1\\PROGRAM\\*.SRC", list_flags=1)
    assert items == ["KRC:\\R1\\PROGRAM\\A.SRC", "KRC:\\R1\\PROGRAM\\SUB\\B.SRC"]
    with pytest.raises(FileOpError):
        share.name_list("KRC:\\R1\\NOPE")


def test_name_list_too_long_for_one_reply_is_code_10(share: ShareFiles) -> None:
    for i in range(700):
        (share.root / "TRACE" / f"trace_{i:04d}_NextGenDrive#3.r64").write_bytes(b"")
    with pytest.raises(FileOpError) as err:
        share.name_list("/TRACE")
    assert err.value.code == CODE_LONG_ANSWER


def test_create_delete_copy_move(share: ShareFiles) -> None:
    share.create("KRC:\\R1\\PROGRAM\\NEW.SRC", 32, always=False)
    assert (share.root / "R1" / "PROGRAM" / "NEW.SRC").read_bytes() == b""
    with pytest.raises(FileOpError):
        share.create("KRC:\\R1\\PROGRAM\\NEW.SRC", 32, always=False)
    share.create("KRC:\\R1\\PROGRAM\\DIR", ITEM_DIR, always=False)
    assert (share.root / "R1" / "PROGRAM" / "DIR").is_dir()
    share.copy("/R1/NEW.SRC", "/R1/COPY.SRC", 0)
    with pytest.raises(FileOpError):
        share.copy("/R1/NEW.SRC", "/R1/COPY.SRC", 0)
    share.copy("/R1/NEW.SRC", "/R1/COPY.SRC", 64)
    share.copy("/R1/COPY.SRC", "/TRACE/MOVED.SRC", 0, move=True)
    assert not share.exists("/R1/COPY.SRC") and share.exists("/TRACE/MOVED.SRC")
    share.set_attribute("/TRACE/MOVED.SRC", ATTR_READONLY, ATTR_READONLY)
    with pytest.raises(FileOpError):
        share.delete("/TRACE/MOVED.SRC", always=False)
    share.delete("/TRACE/MOVED.SRC", always=True)
    share.delete("KRC:\\R1\\PROGRAM\\DIR", always=False)
    assert not share.exists("/TRACE/MOVED.SRC") and not share.exists("KRC:\\R1\\PROGRAM\\DIR")
    with pytest.raises(FileOpError):
        share.delete("KRC:\\", always=True)
    with pytest.raises(FileOpError):
        share.delete("/R1/NOPE.SRC", always=True)


def test_name_list_skips_an_entry_that_vanishes_between_listing_and_stat(tmp_path: Path) -> None:
    """A trace file renamed away while the directory is listed must not break the listing (nor the connection).

    A dangling symlink stands for the vanished file: iterdir() yields it, stat() raises FileNotFoundError.
    """
    trace = tmp_path / "TRACE"
    trace.mkdir()
    (trace / "t1_KRCIpo.dat").write_bytes(b"x")
    (trace / "t1_KRCIpo.r64").symlink_to(trace / "renamed-away.r64")
    items, infos = ShareFiles(tmp_path).name_list("/TRACE/")
    assert [i.upper().rsplit("\\", 1)[-1] for i in items] == ["T1_KRCIPO.DAT"]
    assert len(infos) == 1


def test_create_always_truncates_a_file_and_refuses_the_rest(share: ShareFiles) -> None:
    target = share.root / "R1" / "PROGRAM" / "A.SRC"
    target.write_text("DEF A()\nEND\n")
    share.create("/R1/A.SRC", ITEM_MODULE, always=True)
    assert target.read_bytes() == b""
    for name, item, always, code in [
        ("/R1/A.SRC", ITEM_MODULE, False, CODE_ACCESS),  # exists
        ("/R1/A.SRC", ITEM_DIR, True, CODE_ACCESS),  # exists as a file
        ("KRC:\\R1\\PROGRAM", ITEM_MODULE, True, CODE_ACCESS),  # exists as a directory
        ("KRC:\\R1\\NOPE\\B.SRC", ITEM_MODULE, True, CODE_ARGUMENT),  # no such directory
        ("KRC:\\R1\\..\\..\\B.SRC", ITEM_MODULE, True, CODE_ARGUMENT),  # leaves the share
    ]:
        with pytest.raises(FileOpError) as err:
            share.create(name, item, always=always)
        assert err.value.code == code, name
    target.chmod(0o444)
    with pytest.raises(FileOpError) as err:
        share.create("/R1/A.SRC", ITEM_MODULE, always=True)
    assert err.value.code == CODE_ACCESS
    share.create("KRC:\\R1\\PROGRAM", ITEM_DIR, always=True)  # an existing directory, always: nothing to do
    assert not (share.root.parent / "B.SRC").exists()


def test_delete_refuses_a_non_empty_directory_and_a_read_only_file_without_always(share: ShareFiles) -> None:
    (share.root / "TRACE" / "t_KRCIpo.dat").write_text("x")
    for name, always in [("C:\\KRC\\ROBOTER\\TRACE", True), ("C:\\KRC\\ROBOTER\\", True)]:
        with pytest.raises(FileOpError) as err:
            share.delete(name, always=always)
        assert err.value.code == CODE_ACCESS
    share.set_attribute("/TRACE/t_KRCIpo.dat", ATTR_READONLY, ATTR_READONLY)
    with pytest.raises(FileOpError) as err:
        share.delete("/TRACE/t_KRCIpo.dat", always=False)
    assert err.value.code == CODE_ACCESS and (share.root / "TRACE" / "t_KRCIpo.dat").exists()
    share.set_attribute("/TRACE/t_KRCIpo.dat", 0, ATTR_READONLY)
    share.delete("/trace/T_KRCIPO.DAT", always=False)  # case-insensitive, as on Windows
    share.delete("C:\\KRC\\ROBOTER\\TRACE", always=False)  # now empty
    assert not (share.root / "TRACE").exists()
    with pytest.raises(FileOpError) as err:
        share.delete("/TRACE/t_KRCIpo.dat", always=True)
    assert err.value.code == CODE_ARGUMENT


def test_set_attribute_read_only_leaves_directories_writable(share: ShareFiles) -> None:
    share.set_attribute("KRC:\\R1\\PROGRAM", ATTR_READONLY, ATTR_READONLY)
    assert not share.properties("KRC:\\R1\\PROGRAM").attributes & ATTR_READONLY
    (share.root / "R1" / "PROGRAM" / "A.SRC").write_text("x")
    share.set_attribute("/R1/A.SRC", ATTR_READONLY, 0)  # bit outside the mask: no change
    assert not share.properties("/R1/A.SRC").attributes & ATTR_READONLY
    with pytest.raises(FileOpError) as err:
        share.set_attribute("/R1/NOPE.SRC", ATTR_READONLY, ATTR_READONLY)
    assert err.value.code == CODE_ARGUMENT


def test_copy_overwrites_only_with_its_flags(share: ShareFiles) -> None:
    prog = share.root / "R1" / "PROGRAM"
    (prog / "A.SRC").write_text("new")
    (prog / "B.SRC").write_text("old")
    with pytest.raises(FileOpError) as err:
        share.copy("/R1/A.SRC", "/R1/B.SRC", 0)
    assert err.value.code == CODE_ACCESS and (prog / "B.SRC").read_text() == "old"
    (prog / "B.SRC").chmod(0o444)
    with pytest.raises(FileOpError) as err:
        share.copy("/R1/A.SRC", "/R1/B.SRC", COPY_OVERWRITE_EXISTS)
    assert err.value.code == CODE_ACCESS and (prog / "B.SRC").read_text() == "old"
    share.copy("/R1/A.SRC", "/R1/B.SRC", COPY_OVERWRITE_EXISTS | COPY_OVERWRITE_READ)
    assert (prog / "B.SRC").read_text() == "new" and (prog / "A.SRC").read_text() == "new"
    with pytest.raises(FileOpError) as err:
        share.copy("/R1/A.SRC", "/R1/A.SRC", COPY_OVERWRITE_EXISTS)
    assert err.value.code == CODE_ACCESS
    with pytest.raises(FileOpError) as err:
        share.copy("/R1/A.SRC", "KRC:\\R1\\PROGRAM", COPY_OVERWRITE_EXISTS)  # a file onto a directory
    assert err.value.code == CODE_ACCESS


@pytest.mark.parametrize("move", [False, True])
def test_copy_and_move_refusals(share: ShareFiles, move: bool) -> None:
    (share.root / "R1" / "PROGRAM" / "A.SRC").write_text("x")
    for source, destination, code in [
        ("/R1/NOPE.SRC", "/R1/B.SRC", CODE_ARGUMENT),  # no source
        ("/R1/A.SRC", "KRC:\\R1\\NOPE\\B.SRC", CODE_ARGUMENT),  # no target directory
        ("KRC:\\R1", "KRC:\\R1\\PROGRAM\\R1", CODE_ARGUMENT),  # into itself
        ("KRC:\\", "/TRACE/ALL", CODE_ACCESS),  # the share itself
        ("/R1/A.SRC", "KRC:\\R1\\..\\..\\A.SRC", CODE_ARGUMENT),  # leaves the share
        ("C:\\Windows\\win.ini", "/R1/A.INI", CODE_ARGUMENT),
    ]:
        with pytest.raises(FileOpError) as err:
            share.copy(source, destination, COPY_OVERWRITE_EXISTS, move=move)
        assert err.value.code == code, (source, destination)
    assert (share.root / "R1" / "PROGRAM" / "A.SRC").read_text() == "x"
    assert not (share.root.parent / "A.SRC").exists()


def test_move_and_copy_of_a_directory_tree(share: ShareFiles) -> None:
    sub = share.root / "R1" / "PROGRAM" / "SUB"
    sub.mkdir()
    (sub / "B.SRC").write_text("b")
    share.copy("KRC:\\R1\\PROGRAM\\SUB", "KRC:\\R1\\PROGRAM\\SUB2", 0)
    assert (share.root / "R1" / "PROGRAM" / "SUB2" / "B.SRC").read_text() == "b" and (sub / "B.SRC").exists()
    share.copy("KRC:\\R1\\PROGRAM\\SUB2", "/TRACE/SUB3", 0, move=True)
    assert not (share.root / "R1" / "PROGRAM" / "SUB2").exists()
    assert (share.root / "TRACE" / "SUB3" / "B.SRC").read_text() == "b"
    (share.root / "TRACE" / "X.SRC").write_text("x")
    (share.root / "TRACE" / "X.SRC").chmod(0o444)
    share.copy("/TRACE/X.SRC", "/R1/X.SRC", 0, move=True)  # a read-only file may be moved
    assert (share.root / "R1" / "PROGRAM" / "X.SRC").read_text() == "x"
