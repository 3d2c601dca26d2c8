"""Writer -> reader round trips, the file set on disk, and reading by name rather than position."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon.errors import DataError
from rgse_daemon.trace import read_trace_file, read_trace_set
from rgse_daemon.trace.channels import DRIVE_CHANNEL_UNITS, ISTMOMENT, drive_module
from simulators.krc4.tracefiles import write_trace_set
from tests.support.tracehelpers import drive_channels, edit_channel, write_small_set


@pytest.mark.parametrize("storage", ["BLOCK", "CHANNEL"])
@pytest.mark.parametrize("period_s", [0.001, 0.004, 0.012])
@pytest.mark.parametrize(("factor", "offset"), [(1.0, 0.0), (0.001, 12.5), (-2.0, -7.25)])
def test_round_trip(tmp_path: Path, storage: str, period_s: float, factor: float, offset: float) -> None:
    n = 257
    modules = {drive_module(3): drive_channels(n, 3), drive_module(5): drive_channels(n, 5)}
    paths = write_trace_set(
        tmp_path, "cal00_l01", period_s, modules, storage=storage, factor=factor, offset=offset, prog_text="DEF a()"
    )
    assert {p.name for p in paths} == {
        "cal00_l01_PROG.TXT",
        *(f"cal00_l01_NextGenDrive#{k}.{ext}" for k in (3, 5) for ext in ("dat", "r64", "trc")),
    }
    ts = read_trace_set(tmp_path, "cal00_l01")
    assert set(ts.files) == {"NextGenDrive#3", "NextGenDrive#5"}
    for module, channels in modules.items():
        tf = ts.files[module]
        assert tf.period_s == period_s
        assert tf.n_samples == n
        assert tf.module == module
        np.testing.assert_allclose(tf.time_s(), np.arange(n) * period_s, rtol=1e-12, atol=0.0)
        assert list(tf.channels) == ["Zeit", *DRIVE_CHANNEL_UNITS]
        for name, (values, unit) in channels.items():
            ch = ts.channel(module, name)
            assert ch.unit == unit
            assert ch.module == module
            assert ch.values.dtype == np.float64
            assert not ch.values.flags.writeable
            np.testing.assert_allclose(ch.values, values, rtol=1e-12, atol=1e-9)
        for file_name, digest in tf.sha256.items():
            assert digest == hashlib.sha256((tmp_path / file_name).read_bytes()).hexdigest()
        assert set(tf.sha256) == {f"cal00_l01_{module}.dat", f"cal00_l01_{module}.r64"}
    raw_block = np.fromfile(tmp_path / "cal00_l01_NextGenDrive#3.r64", dtype="<f8")
    physical = modules["NextGenDrive#3"]["Istmoment"][0]
    stored = raw_block.reshape(n, 7)[:, 5] if storage == "BLOCK" else raw_block[5 * n : 6 * n]
    np.testing.assert_allclose(stored, (physical - offset) / factor, rtol=1e-12)


def test_dat_is_crlf_latin1_diadem(tmp_path: Path) -> None:
    write_small_set(tmp_path)
    raw = (tmp_path / "run1_NextGenDrive#3.dat").read_bytes()
    text = raw.decode("iso-8859-1")
    assert text.startswith("DIAEXTENDED  {@:ENGLISH\r\n")
    assert "\n" not in text.replace("\r\n", "")
    first_channel = text.split("#BEGINCHANNELHEADER")[1]
    for line in ("200,Zeit", "202,s", "210,IMPLIZIT", "240,0.0", "241,0.012"):
        assert f"\r\n{line}\r\n" in first_channel
    assert (tmp_path / "run1_PROG.TXT").exists() is False
    assert b"Rate_us=12000" in (tmp_path / "run1_NextGenDrive#3.trc").read_bytes()


def test_prog_text_is_written_with_crlf(tmp_path: Path) -> None:
    write_small_set(tmp_path, prog_text="DEF rgse_meas()\nPTP HOME\nEND\n")
    assert (tmp_path / "run1_PROG.TXT").read_bytes() == b"DEF rgse_meas()\r\nPTP HOME\r\nEND\r\n"


def test_writer_leaves_no_temporary_files(tmp_path: Path) -> None:
    write_small_set(tmp_path)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_modules_subset_and_missing_module(tmp_path: Path) -> None:
    write_small_set(tmp_path)
    ts = read_trace_set(tmp_path, "run1", modules=["NextGenDrive#5"])
    assert list(ts.files) == ["NextGenDrive#5"]
    with pytest.raises(DataError, match=r"run1_NextGenDrive#3\.dat"):
        ts.channel("NextGenDrive#3", ISTMOMENT)
    with pytest.raises(DataError, match=r"run1_NextGenDrive#2\.dat"):
        read_trace_set(tmp_path, "run1", modules=["NextGenDrive#5", "NextGenDrive#2"])
    with pytest.raises(DataError, match="no trace files"):
        read_trace_set(tmp_path, "run9")
    ts_all = read_trace_set(tmp_path, "run1", max_workers=1)
    assert set(ts_all.files) == {"KRCIpo", "NextGenDrive#3", "NextGenDrive#5"}
    assert len(ts_all.sha256) == 6


def test_trace_name_prefix_does_not_swallow_other_traces(tmp_path: Path) -> None:
    write_small_set(tmp_path, name="dut")
    write_small_set(tmp_path, name="dut_l02")
    assert set(read_trace_set(tmp_path, "dut").files) == {"KRCIpo", "NextGenDrive#3", "NextGenDrive#5"}
    assert set(read_trace_set(tmp_path, "dut_l02").files) == {"KRCIpo", "NextGenDrive#3", "NextGenDrive#5"}


def test_channels_found_by_name_not_position(tmp_path: Path) -> None:
    """Reverse the channel blocks in the header: the values must follow the names (pointer 221), not the order."""
    modules = write_small_set(tmp_path)
    dat = tmp_path / "run1_NextGenDrive#3.dat"
    text = dat.read_bytes().decode("iso-8859-1")
    head, *blocks = text.split("\r\n#BEGINCHANNELHEADER")
    zeit, explicit = blocks[0], blocks[1:]
    dat.write_bytes("\r\n#BEGINCHANNELHEADER".join([head, zeit, *reversed(explicit)]).encode("iso-8859-1"))
    tf = read_trace_file(dat)
    assert list(tf.channels)[1] == "Iststrom"
    for name, (values, _unit) in modules["NextGenDrive#3"].items():
        np.testing.assert_allclose(tf.channel(name).values, values, rtol=1e-12)


def test_missing_channel_names_the_file(tmp_path: Path) -> None:
    write_small_set(tmp_path)
    tf = read_trace_file(tmp_path / "run1_KRCIpo.dat")
    with pytest.raises(DataError, match=r"run1_KRCIpo\.dat: no channel 'Istmoment'"):
        tf.channel("Istmoment")


def test_zero_samples(tmp_path: Path) -> None:
    write_trace_set(tmp_path, "empty", 0.004, {"NextGenDrive#1": {"Istmoment": (np.empty(0), "Nm")}})
    tf = read_trace_file(tmp_path / "empty_NextGenDrive#1.dat")
    assert tf.n_samples == 0
    assert tf.channel("Istmoment").values.size == 0
    assert tf.period_s == 0.004


def test_unknown_codes_are_kept(tmp_path: Path) -> None:
    write_small_set(tmp_path)
    dat = tmp_path / "run1_NextGenDrive#3.dat"
    edit_channel(dat, "Istmoment", 299, "something KUKA-specific äö")
    tf = read_trace_file(dat)
    assert tf.channel("Istmoment").header[299] == "something KUKA-specific äö"
    assert tf.channel("Istmoment").header[253] == "not monotone"
    assert tf.global_header[112] == "High -> Low"


def test_windows_1252_text_in_values_is_kept_whole(tmp_path: Path) -> None:
    """Bytes that str.splitlines takes for line ends (0x85 is Windows-1252 "…", 0x0C a form feed, 0x1E a record
    separator) inside a value are text of that value, not line breaks; trailing ones are kept too."""
    write_small_set(tmp_path)
    dat = tmp_path / "run1_NextGenDrive#3.dat"
    comment = "Istmoment\x85 motor side\x0cpage\x1eend\x85"
    edit_channel(dat, "Istmoment", 201, comment)
    tf = read_trace_file(dat)
    assert tf.channel("Istmoment").comment == comment
    assert tf.channel("Istmoment").values.shape == (40,)


def test_english_spelling_lf_channel_storage_hand_written(tmp_path: Path) -> None:
    """A header as DIAdem itself writes it (English keywords, LF, CHANNEL storage, calibration on one channel)."""
    torque_raw = np.array([1.0, -2.0, 3.5, -4.25])
    current = np.array([0.5, 0.25, -0.125, 8.0])
    np.concatenate([current, torque_raw]).astype("<f8").tofile(tmp_path / "m.R64")
    header = "\n".join(
        [
            "DIAEXTENDED  {@:ENGLISH",
            "#BEGINGLOBALHEADER",
            "1,WINDOWS 32Bit",
            "2,DIAdem 2020",
            "104,03-14-2024",
            "105,10:11:12",
            "#ENDGLOBALHEADER",
            "#BEGINCHANNELHEADER",
            "200,Zeit",
            "202,s",
            "210,IMPLICIT",
            "220,4",
            "240,10.0",
            "241,0.004",
            "#ENDCHANNELHEADER",
            "#BEGINCHANNELHEADER",
            "200,Istmoment",
            "201,torque A3",
            "202,Nm",
            "210,EXPLICIT",
            "211,C:\\KRC\\ROBOTER\\TRACE\\m.R64",
            "213,CHANNEL",
            "214,REAL64",
            "220,4",
            "221,5",
            "240,100",
            "241,2",
            "#ENDCHANNELHEADER",
            "#BEGINCHANNELHEADER",
            "200,Iststrom",
            "202,A",
            "210,EXPLICIT",
            "211,m.R64",
            "213,CHANNEL",
            "214,REAL64",
            "220,4",
            "221,1",
            "#ENDCHANNELHEADER",
            "",
        ]
    )
    (tmp_path / "x_NextGenDrive#3.dat").write_bytes(header.encode("iso-8859-1"))
    tf = read_trace_file(tmp_path / "x_NextGenDrive#3.dat")
    assert tf.module == "NextGenDrive#3"
    assert tf.period_s == 0.004
    np.testing.assert_array_equal(tf.time_s(), [10.0, 10.004, 10.008, 10.012])
    np.testing.assert_array_equal(tf.channel("Istmoment").values, torque_raw * 2 + 100)
    np.testing.assert_array_equal(tf.channel("Iststrom").values, current)
    assert tf.channel("Istmoment").comment == "torque A3"
    assert tf.global_header[2] == "DIAdem 2020"
    assert tf.data_path == tmp_path / "m.R64"


def test_explicit_time_channel(tmp_path: Path) -> None:
    t = 5.0 + np.arange(6) * 0.004
    np.column_stack([t, np.arange(6.0)]).astype("<f8").tofile(tmp_path / "e.r64")
    blocks = []
    for col, (name, unit) in enumerate([("Zeit", "s"), ("Istmoment", "Nm")], start=1):
        blocks += ["#BEGINCHANNELHEADER", f"200,{name}", f"202,{unit}", "210,EXPLIZIT", "211,e.r64",
                   "213,BLOCK", "214,REAL64", "220,6", f"221,{col}", "#ENDCHANNELHEADER"]  # fmt: skip
    text = "\r\n".join(["#BEGINGLOBALHEADER", "#ENDGLOBALHEADER", *blocks])
    dat = tmp_path / "e_KRCIpo.dat"
    dat.write_bytes(text.encode("iso-8859-1"))
    tf = read_trace_file(dat)
    assert tf.period_s == pytest.approx(0.004, rel=1e-12)
    np.testing.assert_array_equal(tf.time_s(), t)
    swapped = np.column_stack([t[::-1], np.arange(6.0)]).astype("<f8")
    swapped.tofile(tmp_path / "e.r64")
    with pytest.raises(DataError, match=r"e_KRCIpo\.dat.*not strictly increasing"):
        read_trace_file(dat)
    t_uneven = t.copy()
    t_uneven[3] += 0.001
    np.column_stack([t_uneven, np.arange(6.0)]).astype("<f8").tofile(tmp_path / "e.r64")
    with pytest.raises(DataError, match=r"e_KRCIpo\.dat.*non-uniform step"):
        read_trace_file(dat)


def test_writer_refuses_bad_arguments(tmp_path: Path) -> None:
    ok = {"NextGenDrive#1": {"Istmoment": (np.zeros(3), "Nm")}}
    with pytest.raises(ValueError, match="different lengths"):
        write_trace_set(tmp_path, "t", 0.004, {"M": {"a": (np.zeros(3), "Nm"), "b": (np.zeros(4), "Nm")}})
    with pytest.raises(ValueError, match="finite or NaN"):  # NaN is a missing sample (the no-value marker), inf not
        write_trace_set(tmp_path, "t", 0.004, {"M": {"a": (np.array([1.0, np.inf]), "Nm")}})
    with pytest.raises(ValueError, match="period_s"):
        write_trace_set(tmp_path, "t", 0.0, ok)
    with pytest.raises(ValueError, match="storage"):
        write_trace_set(tmp_path, "t", 0.004, ok, storage="ROWS")
    with pytest.raises(ValueError, match="factor"):
        write_trace_set(tmp_path, "t", 0.004, ok, factor=0.0)
    with pytest.raises(ValueError, match="trace name"):
        write_trace_set(tmp_path, "a/b", 0.004, ok)
    with pytest.raises(ValueError, match="contains '_'"):
        write_trace_set(tmp_path, "t", 0.004, {"Next_Gen": {"a": (np.zeros(3), "Nm")}})
    with pytest.raises(ValueError, match="implicit time channel"):
        write_trace_set(tmp_path, "t", 0.004, {"M": {"Zeit": (np.zeros(3), "s")}})
    assert list(tmp_path.iterdir()) == []


def test_without_sha256_reads_the_same_values(tmp_path: Path) -> None:
    write_small_set(tmp_path)
    hashed = read_trace_set(tmp_path, "run1")
    plain = read_trace_set(tmp_path, "run1", with_sha256=False)
    assert plain.sha256 == {}
    assert len(hashed.sha256) == 6
    for module, tf in hashed.files.items():
        for name, channel in tf.channels.items():
            np.testing.assert_array_equal(plain.channel(module, name).values, channel.values)


def test_files_appear_by_rename_data_before_header(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each file is renamed into place from a temporary name in the same directory; .r64 before .dat."""
    import rgse_daemon.durable as tracefiles  # the simulator writes its trace files with the project's durable helper

    renames: list[tuple[Path, Path]] = []
    real_replace = tracefiles.os.replace

    def recording_replace(src: str, dst: Path) -> None:
        renames.append((Path(src), Path(dst)))
        real_replace(src, dst)

    monkeypatch.setattr(tracefiles.os, "replace", recording_replace)
    write_small_set(tmp_path, prog_text="DEF a()")
    paths = sorted(tmp_path.iterdir())
    assert len(paths) == 10
    assert {dst for _src, dst in renames} == set(paths)
    for src, dst in renames:
        assert src.parent == dst.parent == tmp_path
        assert src.name.startswith(f".{dst.name}.")
    order = [dst.name for _src, dst in renames]
    for module in ("KRCIpo", "NextGenDrive#3", "NextGenDrive#5"):
        assert order.index(f"run1_{module}.r64") < order.index(f"run1_{module}.dat")


def test_failed_write_leaves_no_temporary_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import rgse_daemon.durable as tracefiles  # the simulator writes its trace files with the project's durable helper

    def failing_fsync(fd: int) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(tracefiles.os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="disk full"):
        write_small_set(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_a_missing_sample_is_written_as_the_declared_no_value_and_read_back_as_nan(tmp_path):
    """The simulator's writer puts DIAdem's no-value marker (global header code 111) where a sample is missing."""
    values = np.array([1.0, np.nan, 3.0, 4.0])
    write_trace_set(tmp_path, "t", 0.004, {"M": {"a": (values, "Nm")}})
    assert np.fromfile(tmp_path / "t_M.r64", "<f8")[1] == 9.9e34
    ch = read_trace_file(tmp_path / "t_M.dat").channel("a")
    assert ch.n_missing == 1 and np.isnan(ch.values[1]) and ch.values[3] == 4.0
