"""CAL.json ``fit.uncertainty.refit_basis``: a file written before the refits of a model with a ``sat`` term were
re-expressed in the calibration's basis is measured with a warning; the files ``rgse calibrate`` writes now, and
older files without a sat curve, without one (interfaces §3)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rgse_daemon import calfile
from rgse_daemon.cli import main
from rgse_daemon.pipeline.inline import stale_refits_warning
from tests.support.cli import fitted_dirs, one_line_error

NEEDLE = "was written before refit_basis"


@pytest.fixture(scope="module")
def dirs(tmp_path_factory) -> Path:
    """A Table-1-like campaign fitted with a sat model (``CAL.json``, axis-sat-sat) and without (``quad.json``)."""
    root = fitted_dirs(tmp_path_factory.mktemp("refit_basis"), "axis-sat-sat", n_samples=600)
    assert main(["calibrate", "--campaign", str(root / "cal"), "--out", str(root / "quad.json"),
                 "--method", "axis-quad"]) == 0
    return root


def mass(capsys, dirs: Path, cal: Path) -> dict:
    capsys.readouterr()
    code = main(["mass", "--traces", str(dirs / "dut"), "--calibration", str(cal), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == (4 if doc["warnings"] else 0)  # interfaces §1.1
    return doc


def sat_methods(doc: dict) -> list[str]:
    """The chosen model and alternatives of a CAL.json document whose curves have a sat term, in the file's order."""
    entries = [doc, *doc["fit"]["alternatives"]]
    return [e["method"] for e in entries if any("sat" in m.get("terms", ()) for m in e["models"].values())]


def rewritten(tmp_path: Path, doc: dict, name: str) -> Path:
    """``doc`` sealed over what it holds, as a former version wrote it."""
    path = tmp_path / name
    path.write_text(json.dumps(calfile.seal(doc)))
    return path


def without_refit_basis(doc: dict) -> dict:
    for u in [doc["fit"]["uncertainty"], *(alt["uncertainty"] for alt in doc["fit"]["alternatives"])]:
        del u["refit_basis"]
    return doc


def test_a_new_file_says_its_refits_are_in_the_calibrations_basis_and_measures_without_the_warning(capsys, dirs):
    doc = json.loads((dirs / "CAL.json").read_text())
    assert doc["method"] == "axis-sat-sat" and "axis-sat" in sat_methods(doc)
    assert doc["fit"]["uncertainty"]["refit_basis"] == "calibration"
    assert all(alt["uncertainty"]["refit_basis"] == "calibration" for alt in doc["fit"]["alternatives"])
    res = mass(capsys, dirs, dirs / "CAL.json")
    assert res["method"] == "axis-sat-sat"
    assert not any(NEEDLE in w for w in res["warnings"]), res["warnings"]


def test_a_file_without_refit_basis_and_a_sat_model_draws_the_warning(tmp_path, capsys, dirs):
    """The same file as a version before refit_basis wrote it: the chosen model and a sat alternative named, in the
    JSON result and the printed one; mass and U unchanged (a warning only; these refits happen to be right)."""
    doc = json.loads((dirs / "CAL.json").read_text())
    old = rewritten(tmp_path, without_refit_basis(doc), "old.json")
    names = sat_methods(doc)
    assert names[0] == "axis-sat-sat" and "axis-sat" in names
    warning = stale_refits_warning(names)
    assert warning.startswith(f"CAL.json fit.uncertainty was written before refit_basis: the refits of "
                              f"{', '.join(names)} (a sat term) are in another basis, so U's calibration term may "
                              f"be much too wide and the chosen model's curve may have been replaced by an "
                              f"alternative's; run rgse calibrate on the campaign again to fix it")
    res = mass(capsys, dirs, old)
    assert warning in res["warnings"], res["warnings"]
    new = mass(capsys, dirs, dirs / "CAL.json")
    assert (res["mass_kg"], res["U_kg"], res["method"]) == (new["mass_kg"], new["U_kg"], new["method"])
    assert main(["mass", "--traces", str(dirs / "dut"), "--calibration", str(old)]) == 4  # a result with warnings
    assert f"warning: {warning}\n" in capsys.readouterr().out


def test_a_file_without_refit_basis_warns_for_a_sat_alternative_and_not_without_any_sat_curve(tmp_path, capsys,
                                                                                              dirs):
    """axis-quad's own refits were always right; its sat alternatives' were not (they can stand in for it). With them
    dropped, no curve of the file has a sat term: no warning."""
    doc = without_refit_basis(json.loads((dirs / "quad.json").read_text()))
    names = sat_methods(doc)
    assert doc["method"] == "axis-quad" and names and "axis-quad" not in names
    res = mass(capsys, dirs, rewritten(tmp_path, doc, "alts.json"))
    assert stale_refits_warning(names) in res["warnings"], res["warnings"]
    doc["fit"]["alternatives"] = [alt for alt in doc["fit"]["alternatives"] if alt["method"] not in names]
    assert doc["fit"]["alternatives"] and not sat_methods(doc)
    none = rewritten(tmp_path, doc, "nosat.json")
    res = mass(capsys, dirs, none)
    assert res["method"] == "axis-quad"
    assert not any(NEEDLE in w for w in res["warnings"]), res["warnings"]
    assert "refit_basis" not in none.read_text()


@pytest.mark.parametrize("value", ["own", "", 2, None])
def test_an_unknown_refit_basis_is_refused_naming_the_field(tmp_path, capsys, dirs, value):
    doc = json.loads((dirs / "CAL.json").read_text())
    if value is None:  # an alternative's record
        doc["fit"]["alternatives"][1]["uncertainty"]["refit_basis"] = "tau"
        field, shown = "fit.alternatives[1].uncertainty.refit_basis", "'tau'"
    else:
        doc["fit"]["uncertainty"]["refit_basis"] = value
        field, shown = "fit.uncertainty.refit_basis", repr(value)
    bad = rewritten(tmp_path, doc, "bad.json")
    err = one_line_error(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(bad)])
    assert err.endswith(f"{bad}: {field}: unknown value {shown} (known: calibration; absent in files written "
                        f"before it)"), err  # the file named, as every error of calfile.read names it
