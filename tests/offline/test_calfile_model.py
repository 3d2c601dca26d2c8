"""The typed model of CAL.json (rgse_daemon/calfile/model.py): every shape the project has written still reads, a
fitted calibration round-trips (build -> write -> read -> equal), and a damaged field is named, never a KeyError.

cal_json_versions/ holds files written by the project's own code at earlier commits (``rgse calibrate`` of the
paper's Table 1 points, or of tests/support's synthetic campaign, run from that commit's tree):
73d42fd the first CAL.json; 96164b3 fit.uncertainty and n_points; f14872f per-axis models, alternatives with their
own U, envelope; 3aca899 fit.sample_period_s; 8a597f0 uncertainty.refit_basis; af28224 (simcampaign seed 3, a warmer
loop, ``--drift-prior 1e-4``) fit.thermal, fit.set_aside and thermal_state_k, but not the prior its screen used
(fit.screening_drift_prior_per_k came after it)."""

from __future__ import annotations

import copy
import gzip
import json
import re
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.analysis.calibration import fit_campaign
from rgse_daemon.errors import DataError
from tests.support.campaign import write_campaign

VERSIONS = Path(__file__).parent / "cal_json_versions"
OLD = sorted(p.name.removesuffix(".json.gz") for p in VERSIONS.glob("*.json.gz"))


def _old(name: str) -> dict:
    return json.loads(gzip.decompress((VERSIONS / f"{name}.json.gz").read_bytes()))


def _leaves(d, path=""):
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _leaves(v, f"{path}.{k}" if path else k)
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from _leaves(v, f"{path}[{i}]")
    else:
        yield path, d


def test_the_versions_are_all_there():
    assert OLD == ["campaign_3aca899", "campaign_8a597f0", "campaign_96164b3", "campaign_af28224", "campaign_f14872f",
                   "points_73d42fd"]


@pytest.mark.parametrize("name", OLD)
def test_every_older_file_reads_and_keeps_its_values(tmp_path, name):
    doc = _old(name)
    path = tmp_path / "CAL.json"
    path.write_text(json.dumps(doc))
    cal = calfile.read(path)  # its calibration_id still matches: the file as that version wrote it
    assert cal.calibration_id == doc["calibration_id"] and cal.method == doc["method"] and cal.robot == doc["robot"]
    assert (cal.bias.a3_nm, cal.bias.a5_nm) == (doc["bias_nm"]["A3"], doc["bias_nm"]["A5"])
    assert cal.fit.loo_mean_abs_err_pct == doc["fit"]["loo_mean_abs_err_pct"]
    assert (cal.fit.uncertainty is None) == ("uncertainty" not in doc["fit"])
    assert (cal.fit.envelope is None) == ("envelope" not in doc["fit"])
    assert (cal.fit.sample_period_s is None) == ("sample_period_s" not in doc["fit"])
    assert (cal.fit.thermal is None) == ("thermal" not in doc["fit"])
    assert (cal.fit.set_aside is None) == ("set_aside" not in doc["fit"])
    assert cal.fit.screening_drift_prior_per_k is None  # no file before it recorded the screen's prior
    assert len(cal.alternatives()) == len(doc["fit"].get("alternatives", []))
    assert np.isfinite(cal.calibration.mass_kg(2000.0, 400.0))
    mc = cal.mass_calibration()
    assert mc.bias_a3_nm == doc["bias_nm"]["A3"] and len(mc.alternative_uncertainty) == len(mc.alternatives)
    # written back from the model, every value the old file holds is kept (the model adds, never changes)
    again = dict(_leaves(cal.to_dict()))
    changed = {k: (v, again.get(k, "missing")) for k, v in _leaves(doc)
               if again.get(k, "missing") != v and not k.endswith(".scheme")}
    assert not changed, changed


def _fitted(tmp_path: Path) -> calfile.CalFile:
    write_campaign(tmp_path / "camp", n_samples=400)
    return fit_campaign(tmp_path / "camp", "auto")[0]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory: pytest.TempPathFactory) -> calfile.CalFile:
    return _fitted(tmp_path_factory.mktemp("calmodel"))


def test_a_fitted_calibration_round_trips(tmp_path, fitted):
    path = tmp_path / "CAL.json"
    calfile.write(path, fitted)
    text = path.read_text()
    back = calfile.read(path)
    assert back.to_dict() == fitted.to_dict() == json.loads(text)
    assert back.calibration_id == fitted.calibration_id == calfile.content_id(json.loads(text))
    calfile.write(tmp_path / "again.json", back)
    assert (tmp_path / "again.json").read_text() == text  # byte for byte
    # every section the campaign gives is there, typed
    assert back.fit.validation is not None and back.fit.uncertainty is not None and back.fit.envelope is not None
    assert back.fit.alternatives is not None and back.fit.set_aside is not None and back.g_u_m_s2 is not None
    assert back.fit.sample_period_s == pytest.approx(0.004)
    assert back.fit.screening_drift_prior_per_k == 0.003  # the default prior the campaign's screen allowed


def _every_path(d, path=()):
    yield path
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _every_path(v, (*path, k))
    elif isinstance(d, list) and d:
        yield from _every_path(d[0], (*path, 0))


def _edit(doc: dict, path: tuple, value) -> dict:
    out = copy.deepcopy(doc)
    node = out
    for k in path[:-1]:
        node = node[k]
    if value is _DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return calfile.seal(out)


_DELETE = object()


@pytest.mark.parametrize("value", [_DELETE, "text", []], ids=["removed", "text", "list"])
def test_a_damaged_field_is_a_data_error_never_a_crash(tmp_path, fitted, value):
    """Each field of the file (down to the first entry of every list), removed or of a wrong type: the file reads
    (the field is optional or free text) or is refused with a DataError; never a KeyError or TypeError."""
    doc = fitted.to_dict()
    seen = 0
    for path in _every_path(doc):
        if not path or path[-1] in ("calibration_id", "created_utc") or path[0] == "torsional":
            continue
        if any(k in ("bootstrap_params", "reference_params", "interior_torque_nm", "covariance",
                     "covariance_reference_mass", "heldout_residual_nm", "points_nm") for k in path[:-1]):
            continue  # numeric matrices: one entry of each is enough
        bad = _edit(doc, path, value)
        try:
            calfile.parse(bad)
        except DataError as exc:
            assert "CAL.json" in str(exc)
        seen += 1
    assert seen > 100


def test_a_field_error_names_the_field(fitted):
    doc = fitted.to_dict()
    cases = [
        (("bias_nm", "A3"), "x", "bias_nm.A3 must be a finite number"),
        (("fit", "alternatives", 0, "models"), _DELETE, "fit.alternatives[0] lacks 'models'"),
        (("fit", "validation", "heldout_axis_rms_nm", "A5"), None, "fit.validation.heldout_axis_rms_nm.A5"),
        (("fit", "set_aside"), {}, "fit.set_aside must be a list"),
        (("fit", "n_points"), 2.5, "fit.n_points must be a whole number"),
        (("fit", "loo_max_abs_err_kg"), _DELETE, "fit lacks 'loo_max_abs_err_kg'"),
        (("thermal_state_k",), {"A3": "warm"}, "thermal_state_k.A3 must be a finite number"),
        (("fit", "screening_drift_prior_per_k"), "x", "fit.screening_drift_prior_per_k must be a finite number"),
        (("fit", "screening_drift_prior_per_k"), 0.3, "fit.screening_drift_prior_per_k = 0.3 per K is not a bound on "
                                                       "|β|: it must lie in (0, 0.05]"),
        (("fit", "screening_drift_prior_per_k"), 0, "fit.screening_drift_prior_per_k = 0 per K is not a bound"),
    ]
    for path, value, needle in cases:
        with pytest.raises(DataError, match="^" + re.escape(f"CAL.json: {needle}")):
            calfile.parse(_edit(doc, path, value))
