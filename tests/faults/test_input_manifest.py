"""Bad ``manifest.toml`` and points CSV files get a one-line DataError naming the file, the key or trace and the
problem (exit 2, no traceback), through the real CLI on real directories."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon.cli import main
from rgse_daemon.manifest import load_manifest
from tests.support.cli import fitted_dirs, one_line_error


@pytest.fixture(scope="module")
def dirs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return fitted_dirs(tmp_path_factory.mktemp("manifest"), "gain-linear")



def mass_error(capsys: pytest.CaptureFixture[str], traces: Path, cal: Path) -> str:
    return one_line_error(capsys, ["mass", "--traces", str(traces), "--calibration", str(cal)])


def copy(dirs: Path, tmp_path: Path, name: str) -> tuple[Path, Path]:
    d = tmp_path / name
    shutil.copytree(dirs / name, d)
    return d, d / "manifest.toml"


# --- the file itself ---------------------------------------------------------------------------------------------
def test_manifest_that_is_a_directory_is_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    m.unlink()
    m.mkdir()
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert str(m) in err and "is a directory" in err, err
    assert m.is_dir()


def test_manifest_that_cannot_be_read_is_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    m.unlink()
    m.symlink_to(m.name)  # a loop: an OSError (ELOOP) other than not found, also for root
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert str(m) in err and "cannot read" in err, err


@pytest.mark.parametrize("prefix", ["point = 5\n", "point = [1, 2]\n", 'point = "x"\n'])
def test_point_that_is_not_an_array_of_tables_is_refused(tmp_path, capsys, dirs, prefix):
    d, m = copy(dirs, tmp_path, "cal")
    text = m.read_text()
    m.write_text(prefix + text[text.index("[setup]"):text.index("[[point]]")])
    err = one_line_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")])
    assert str(m) in err and "'point' must be [[point]] tables" in err, err
    assert not (tmp_path / "o.json").exists()


def test_manifest_with_a_utf8_bom_is_read(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    capsys.readouterr()
    assert main(["mass", "--traces", str(d), "--calibration", str(dirs / "CAL.json"), "--json"]) == 0
    plain = capsys.readouterr().out
    m.write_bytes(b"\xef\xbb\xbf" + m.read_bytes())
    assert main(["mass", "--traces", str(d), "--calibration", str(dirs / "CAL.json"), "--json"]) == 0
    assert capsys.readouterr().out == plain


# --- the points CSV (rgse calibrate --points) ----------------------------------------------------------------------
def points_error(capsys: pytest.CaptureFixture[str], tmp_path: Path, text: str) -> str:
    p = tmp_path / "points.csv"
    p.write_text(text)
    err = one_line_error(capsys, ["calibrate", "--points", str(p), "--out", str(tmp_path / "o.json")])
    assert str(p) in err and not (tmp_path / "o.json").exists(), err
    return err


def table1(paper_dir: Path) -> list[str]:
    """The data lines of the paper's Table 1 (header first)."""
    return [ln for ln in (paper_dir / "table1_calibration.csv").read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]


@pytest.mark.parametrize("column", ["m_a3_measured_nm", "mass_kg"])
def test_points_csv_with_a_duplicate_column_is_refused(tmp_path, capsys, paper_dir, column):
    lines = table1(paper_dir)
    k = lines[0].split(",").index(column)
    lines = [",".join([*ln.split(","), ln.split(",")[k]]) for ln in lines]  # the column again, at the end
    err = points_error(capsys, tmp_path, "\n".join(lines) + "\n")
    assert "given twice" in err and column in err, err


@pytest.mark.parametrize(("column", "value"), [("m_a3_measured_nm", "1e300"), ("m_a5_expected_nm", "-2e6"),
                                               ("mass_kg", "1e200")])
def test_points_csv_with_an_implausible_value_is_refused(tmp_path, capsys, paper_dir, column, value):
    lines = table1(paper_dir)
    k = lines[0].split(",").index(column)
    cells = lines[3].split(",")
    cells[k] = value
    lines[3] = ",".join(cells)
    err = points_error(capsys, tmp_path, "\n".join(lines) + "\n")
    assert "data row 3" in err and f"column {column}" in err and "plausible" in err, err


@pytest.mark.parametrize(("value", "problem"), [("nan", "whole number"), ("-3", "whole number"),
                                                ("2.5", "whole number"), ("x", "not a number"), ("", "not a number")])
def test_points_csv_n_cb_must_be_a_count(tmp_path, capsys, paper_dir, value, problem):
    lines = table1(paper_dir)
    cells = lines[2].split(",")
    cells[lines[0].split(",").index("n_cb")] = value
    lines[2] = ",".join(cells)
    err = points_error(capsys, tmp_path, "\n".join(lines) + "\n")
    assert "data row 2" in err and "column n_cb" in err and problem in err, err


def test_points_csv_with_a_utf8_bom_is_read(tmp_path, capsys, paper_dir):
    p = tmp_path / "points.csv"
    p.write_bytes(b"\xef\xbb\xbf" + (paper_dir / "table1_calibration.csv").read_bytes())
    assert main(["calibrate", "--points", str(p), "--out", str(tmp_path / "o.json")]) == 0


# --- trace names: each appears once in a manifest ------------------------------------------------------------------
def test_measurement_trace_listed_twice_is_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    m.write_text(m.read_text().replace('"dut_l02"', '"dut_l01"'))
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert str(m) in err and "trace 'dut_l01' appears twice in [measurement]" in err, err


@pytest.mark.parametrize(("old", "new", "places"), [
    ('["cal03_l01", "cal03_l02"]', '["cal02_l01", "cal03_l02"]', "in [[point]] #3 and in [[point]] #4"),
    ('["cal03_l01", "cal03_l02"]', '["cal03_l01", "cal03_l01"]', "twice in [[point]] #4"),
])
def test_campaign_trace_listed_twice_is_refused(tmp_path, capsys, dirs, old, new, places):
    d, m = copy(dirs, tmp_path, "cal")
    assert old in m.read_text()
    m.write_text(m.read_text().replace(old, new))
    err = one_line_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")])
    trace = new.split('"')[1]
    assert str(m) in err and f"trace {trace!r} appears {places}" in err, err
    assert not (tmp_path / "o.json").exists()


TORSIONAL = """
[torsional]
scheme = "paper"
[[torsional.pose]]
name = "meas"
q_deg = [0.0, -90.0, 90.0, 0.0, 0.0, 0.0]
[[torsional.pose]]
name = "A6+90"
q_deg = [0.0, -90.0, 90.0, 0.0, 0.0, 90.0]

[[point]]
kind = "torsional"
mass_kg = 0.0
cog_flange_m = [0.0, 0.0, 0.0]
[point.poses]
meas = [{meas}]
"A6+90" = [{a6}]
"""


def torsional_campaign(dirs: Path, tmp_path: Path, meas: str, a6: str) -> tuple[Path, Path]:
    """The campaign with a bare torsional point appended; its loops tor_l01/tor_l02 are copies of the zero point's."""
    d, m = copy(dirs, tmp_path, "cal")
    for f in d.glob("cal00_l0[12]_*"):
        shutil.copy(f, d / f.name.replace("cal00_", "tor_"))
    m.write_text(m.read_text() + TORSIONAL.format(meas=meas, a6=a6))
    return d, m


@pytest.mark.parametrize(("a6", "places"), [
    ('"tor_l01"', "in [[point]] #15 poses.meas and in [[point]] #15 poses.A6+90"),  # another pose's trace
    ('"cal00_l02"', "in [[point]] #1 and in [[point]] #15 poses.A6+90"),  # a mass point's trace
])
def test_torsional_pose_with_traces_of_another_place_is_refused(tmp_path, capsys, dirs, a6, places):
    d, m = torsional_campaign(dirs, tmp_path, '"tor_l01"', a6)
    err = one_line_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")])
    assert str(m) in err and f"appears {places}" in err, err


def properties_manifest(dut: Path, meas: str, tilted: str) -> str:
    """The measurement directory's manifest as a properties run: two poses with the traces given."""
    return (dut / "manifest.toml").read_text() + f"""
[properties]
scheme = "paper"
mass_kg = 100.0
u_mass_kg = 0.1
[properties.fixture]
mass_kg = 10.288
cog_flange_m = [0.0, 0.0, 0.005]
[[properties.pose]]
name = "meas"
q_deg = [0.0, -90.0, 90.0, 0.0, 0.0, 0.0]
traces = [{meas}]
[[properties.pose]]
name = "A6+90"
q_deg = [0.0, -90.0, 90.0, 0.0, 0.0, 90.0]
traces = [{tilted}]
"""


@pytest.mark.parametrize(("meas", "tilted", "trace", "places"), [
    ('"cog_l01"', '"cog_l01"', "cog_l01", "in [[properties.pose]] #1 and in [[properties.pose]] #2"),
    ('"dut_l01"', '"cog_l02"', "dut_l01", "in [measurement] and in [[properties.pose]] #1"),
])
def test_properties_pose_with_traces_of_another_place_is_refused(tmp_path, capsys, dirs, meas, tilted, trace,
                                                                 places):
    d, m = copy(dirs, tmp_path, "dut")
    for f in d.glob("dut_l0[23]_*"):  # the poses' loops: copies of loops 2 and 3 under names of their own
        shutil.copy(f, d / f.name.replace("dut_l0", "cog_l0").replace("cog_l03", "cog_l01"))
    m.write_text(properties_manifest(d, meas, tilted))
    err = one_line_error(capsys, ["cog", "--traces", str(d), "--calibration", str(dirs / "CAL.json")])
    assert str(m) in err and f"trace {trace!r} appears {places}" in err, err


def shared_properties_dir(dirs: Path, tmp_path: Path, meas: str, tilted: str, flag: str = "true",
                          second: str = "") -> tuple[Path, Path]:
    """The measurement directory as a properties run whose pose ``meas`` shares the mass loops (issue #35: they
    were recorded in it): ``flag`` its ``shares_measurement_loops``, ``second`` that of the tilted pose."""
    d, m = copy(dirs, tmp_path, "dut")
    for f in d.glob("dut_l0[12]_*"):  # the tilted pose's loops and the copies: loops 1 and 2 under other names
        shutil.copy(f, d / f.name.replace("dut_l0", "cog_l0"))
    text = properties_manifest(d, meas, tilted).replace(
        'traces = [' + meas + ']', 'traces = [' + meas + ']\nshares_measurement_loops = ' + flag, 1)
    if second:
        text += f"shares_measurement_loops = {second}\n"
    m.write_text(text)
    return d, m


def test_a_pose_that_shares_the_mass_loops_reads_them_as_copies_of_them_would_read(tmp_path, dirs):
    from rgse_daemon.analysis.cog import read_properties_dir

    shared, _ = shared_properties_dir(dirs, tmp_path / "a", '"dut_l01", "dut_l02"', '"cog_l03"')
    for f in shared.glob("dut_l03_*"):
        shutil.copy(f, shared / f.name.replace("dut_l0", "cog_l0"))
    copies, m = copy(dirs, tmp_path / "b", "dut")
    for f in copies.glob("dut_l0[123]_*"):
        shutil.copy(f, copies / f.name.replace("dut_l0", "cog_l0"))
    m.write_text(properties_manifest(copies, '"cog_l01", "cog_l02"', '"cog_l03"'))
    a, b = read_properties_dir(shared), read_properties_dir(copies)
    assert [r.pose for r in a.readings] == ["meas", "A6+90"]
    for ra, rb in zip(a.readings, b.readings, strict=True):  # the same files, read for the mass and for the pose
        for field in ("q_deg", "torque_nm", "sigma_nm", "motor_temp_k"):  # (NaN: an axis not traced)
            np.testing.assert_array_equal(getattr(ra, field), getattr(rb, field))
    assert "shares_measurement_loops = true" in (shared / "manifest.toml").read_text()


@pytest.mark.parametrize(("meas", "tilted", "flag", "second", "error"), [
    ('"dut_l01"', '"dut_l01"', "true", "", "trace 'dut_l01' appears in [measurement] and [[properties.pose]] #1 "
                                             "and in [[properties.pose]] #2"),  # a shared loop taken again
    ('"dut_l01", "dut_l01"', '"cog_l02"', "true", "", "trace 'dut_l01' appears in [measurement] and "
                                                      "[[properties.pose]] #1 and in [[properties.pose]] #1"),
    ('"dut_l01"', '"dut_l02"', "true", "true", "shares_measurement_loops already holds for pose #1"),
    ('"dut_l01"', '"cog_l02"', '"yes"', "", "shares_measurement_loops must be true or false, got 'yes'"),
])
def test_a_pose_that_shares_the_mass_loops_shares_them_once(tmp_path, capsys, dirs, meas, tilted, flag, second,
                                                            error):
    d, m = shared_properties_dir(dirs, tmp_path, meas, tilted, flag, second)
    err = one_line_error(capsys, ["cog", "--traces", str(d), "--calibration", str(dirs / "CAL.json")])
    assert str(m) in err and error in err, err


# --- unknown keys and values ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(("old", "new", "key", "table", "hint"), [
    ("fixture_mass_kg", "fixture_mas_kg", "fixture_mas_kg", "[measurement]", "fixture_mass_kg"),
    ("lever_difference_m", "lever_difference_m = 1.025\ng_u_ms2 = 0.001\nx", "g_u_ms2", "[setup]", "g_u_m_s2"),
    ("[measurement]", "[measurment]\nx = 1\n[measurement]", "measurment", "", "measurement"),
])
def test_measurement_manifest_unknown_key_is_refused(tmp_path, capsys, dirs, old, new, key, table, hint):
    d, m = copy(dirs, tmp_path, "dut")
    m.write_text(m.read_text().replace(old, new, 1))
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert f"{m}{' ' + table if table else ''}: unknown key {key!r} (did you mean {hint!r}?)" in err, err
    assert "known keys: " in err, err


def test_campaign_point_unknown_key_is_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "cal")
    text = m.read_text()
    k = text.index("[[point]]", text.index("[[point]]") + 1)
    m.write_text(text[:k] + text[k:].replace("mass_kg", "mass_u_kgs = 0.02\nmass_kg", 1))
    err = one_line_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")])
    assert f"{m} [[point]] #2: unknown key 'mass_u_kgs' (did you mean 'mass_u_kg'?)" in err, err
    assert "known keys: kind, mass_kg, lever_a3_m, lever_a5_m, traces, bodies, mass_u_kg" in err, err


@pytest.mark.parametrize(("old", "new", "expected"), [
    ('scheme = "paper"', 'scheme = "bogus"',
     "[torsional]: scheme must be one of paper, full, lever, custom, got 'bogus'"),
    ('scheme = "paper"', 'scheme = "paper"\nposes = 2', "[torsional]: unknown key 'poses' (did you mean 'pose'?)"),
    ('name = "meas"', 'name = "meas"\nq = 1', "[torsional] pose #1: unknown key 'q'"),
    ('cog_flange_m', 'cog_flange = 1\ncog_flange_m',
     "[[point]] #15: unknown key 'cog_flange' (did you mean 'cog_flange_m'?)"),
])
def test_torsional_unknown_key_or_scheme_is_refused(tmp_path, capsys, dirs, old, new, expected):
    d, m = torsional_campaign(dirs, tmp_path, '"tor_l01"', '"tor_l02"')
    text = m.read_text()
    k = text.index("[torsional]")
    m.write_text(text[:k] + text[k:].replace(old, new, 1))
    err = one_line_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")])
    assert f"{m} {expected}" in err, err


@pytest.mark.parametrize(("old", "new", "expected"), [
    ('scheme = "paper"', 'scheme = "bogus"',
     "[properties]: scheme must be one of paper, full, lever, custom, got 'bogus'"),
    ("u_mass_kg", "u_mass_kgs", "[properties]: unknown key 'u_mass_kgs' (did you mean 'u_mass_kg'?)"),
    ("cog_flange_m = [0.0, 0.0, 0.005]", "cog_flange_m = [0.0, 0.0, 0.005]\ndut_abc = [0.0, 0.0, 0.0]",
     "[properties] fixture: unknown key 'dut_abc' (did you mean 'dut_abc_deg'?)"),
    ('name = "meas"', 'name = "meas"\ntrace = ["x"]', "[properties] pose #1: unknown key 'trace' (did you mean"),
])
def test_properties_unknown_key_or_scheme_is_refused(tmp_path, capsys, dirs, old, new, expected):
    d, m = copy(dirs, tmp_path, "dut")
    m.write_text(properties_manifest(d, '"dut_l02"', '"dut_l03"').replace('"dut_l02", "dut_l03"', "").replace(
        old, new, 1))
    err = one_line_error(capsys, ["cog", "--traces", str(d), "--calibration", str(dirs / "CAL.json")])
    assert f"{m} {expected}" in err, err


# --- sample periods (trace header code 241) ------------------------------------------------------------------------
def set_period(directory: Path, trace: str, period: str) -> None:
    """Rewrite the sample period (the implicit time channel's code 241, 4 ms here) in the headers of ``trace``."""
    for dat in directory.glob(f"{trace}_NextGenDrive#*.dat"):
        text = dat.read_text(encoding="iso-8859-1")
        assert text.count("\n241,0.004\n") == 1
        dat.write_text(text.replace("\n241,0.004\n", f"\n241,{period}\n"), encoding="iso-8859-1")


@pytest.mark.parametrize("period", ["1e-300", "1e300", "0.0001", "2.5"])
def test_implausible_sample_period_is_refused(tmp_path, capsys, dirs, period):
    d, _ = copy(dirs, tmp_path, "dut")
    set_period(d, "dut_l02", period)
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert "dut_l02_NextGenDrive#3.dat" in err and f"sample period (code 241) {float(period):g} s" in err, err
    assert "outside the 0.0005 to 1 s" in err, err


def test_measurement_with_mixed_sample_periods_is_refused(tmp_path, capsys, dirs):
    d, _ = copy(dirs, tmp_path, "dut")
    set_period(d, "dut_l03", "0.008")
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert f"{d}: trace 'dut_l03' has sample period 0.008 s, trace 'dut_l01' 0.004 s" in err, err


def test_campaign_with_mixed_sample_periods_is_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "cal")
    for trace in ("cal03_l01", "cal03_l02"):  # one whole point: each point alone has one period
        set_period(d, trace, "0.012")
    err = one_line_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")])
    assert f"{m}: trace 'cal03_l01' has sample period 0.012 s, trace 'cal00_l01' 0.004 s" in err, err
    assert not (tmp_path / "o.json").exists()


def test_torsional_points_with_another_sample_period_are_refused(tmp_path, capsys, dirs):
    d, m = torsional_campaign(dirs, tmp_path, '"tor_l01"', '"tor_l02"')
    for trace in ("tor_l01", "tor_l02"):
        set_period(d, trace, "0.012")
    err = one_line_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")])
    assert f"{m}: trace 'tor_l01' (NextGenDrive#3) has sample period 0.012 s, trace 'cal00_l01' 0.004 s" in err, err


def test_properties_poses_with_mixed_sample_periods_are_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    m.write_text(properties_manifest(d, '"dut_l02"', '"dut_l03"').replace('"dut_l02", "dut_l03"', ""))
    set_period(d, "dut_l03", "0.012")
    err = one_line_error(capsys, ["cog", "--traces", str(d), "--calibration", str(dirs / "CAL.json")])
    assert f"{m}: trace 'dut_l03' (NextGenDrive#3) has sample period 0.012 s, trace 'dut_l02' (NextGenDrive#3) " \
           f"0.004 s" in err, err


# --- issue 31 6h: a manifest is read only from its own directory -------------------------------------------------
def test_manifest_symlinked_out_of_its_directory_is_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    os.replace(m, elsewhere / "manifest.toml")  # a valid manifest: only the link's leaving makes it wrong
    m.symlink_to(elsewhere / "manifest.toml")
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert str(m) in err and "symbolic link leads out" in err, err


def test_manifest_symlinked_inside_its_directory_is_read(tmp_path, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    (d / "keep").mkdir()
    os.replace(m, d / "keep" / "manifest.toml")
    m.symlink_to(Path("keep") / "manifest.toml")
    assert load_manifest(d).measurement_traces
