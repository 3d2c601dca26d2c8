"""What the data set aside, and whether β is applied, where the operator looks (issue #33 item 5): a campaign with
one loop of one point lost to missing samples (DIAdem's no-value marker in every channel) and a DuT knocked during
its third loop, calibrated and measured by the offline commands and recorded in a real store. The calibration's
report (before: it refitted K from every loop, the gapped one included, and refused as inconsistent) names the loop
set aside and why, and β per axis with its span and whether a measurement applies it; the measurement's report marks
each loop it left out, with its reason, in the loop table, and says per axis whether β corrected the loops and
that the DuT lies inside the calibrated envelope. Read back from Chromium's DOM; the certificate's text says the
same."""

from __future__ import annotations

from pathlib import Path

from pypdf import PdfReader

from rgse_daemon.report import build_report
from rgse_daemon.report.certificate import certificate_pdf, latin1, load
from rgse_daemon.store import Repository
from tests.support.chromium import Dom, dump_dom
from tests.support.simcampaign import Knock, simulate_campaign, simulate_measurement, with_gap, write_dirs
from tests.support.storefill import fill

DUT_KG = 120.0


def test_reports_name_the_loops_set_aside_and_the_thermal_state(tmp_path: Path) -> None:
    camp, model = simulate_campaign(4)
    gap = {"cal05_l02": lambda lp: with_gap(lp, "all", 0.2, 0.7)}
    camp.loops[:] = [[gap.get(lp.trace, lambda x: x)(lp) for lp in point] for point in camp.loops]
    meas = simulate_measurement(model, DUT_KG, 0.25, n_loops=5, knock=Knock(2, 0.5, 15.0, -10.0))
    write_dirs(camp, meas, tmp_path / "cal", tmp_path / "dut", {"cal05_l02": slice(50, 225)})
    data = tmp_path / "data"
    with Repository.open(None, data) as repo:
        filled = fill(repo, data, tmp_path / "cal", tmp_path / "dut", tmp_path, method="axis-quad")
        assert [a["loop"] for a in filled.cal_doc["fit"]["set_aside"]] == ["cal05_l02"]
        cal_page = build_report(repo, data, tmp_path / "reports", calibration_id=filled.calibration_id)
        run_page = build_report(repo, data, tmp_path / "reports", run_id=filled.run_id)
        cert = tmp_path / "cert.pdf"
        cert.write_bytes(certificate_pdf(load(repo, filled.run_id)))

    cal = Dom(dump_dom(cal_page))
    assert cal.fields["set_aside.loop"] == ["cal05_l02"]
    (reason,) = cal.fields["set_aside.reason"]
    assert "samples missing" in reason, reason
    # the drift prior the screen allowed, beside what it set aside (the offline command's default)
    assert filled.cal_doc["fit"]["screening_drift_prior_per_k"] == 0.003
    assert cal.fields["screening_drift_prior_per_k"] == ["0.003"]
    for ax in ("A3", "A5"):
        (beta,) = cal.fields[f"thermal.{ax}"]
        assert beta.startswith(f"{ax} β = ") and " K span, " in beta and "applied" in beta, beta

    html = dump_dom(run_page)
    run = Dom(html)
    aside = filled.result["loops_set_aside"]
    assert [a["loop"] for a in aside] == ["dut_l03", "dut_l04", "dut_l05"], aside
    assert run.fields["loop.set_aside"] == [a["reason"] for a in aside]
    assert run.fields["status"] == ["warning"]
    # how the drift was treated per axis, the result's notes (β with its span applied over the DuT's offset, or
    # why not and the bound U carries), and U's thermal term
    notes, applied = filled.result["thermal_notes"], filled.result["thermal_applied"]
    assert set(notes) == set(applied) == {"A3", "A5"}, notes
    for ax, on in applied.items():
        assert notes[ax].startswith("campaign's β = " if on else "not corrected ("), notes
    thermal = (f"A3 {notes['A3']}; A5 {notes['A5']}; thermal term of U: "
               f"u = {filled.result['u_components_kg']['thermal']:.3f} kg")
    assert run.fields["thermal_correction"] == [thermal]
    assert "set aside: " in html and "in the result" in html
    assert run.fields["operating_point"] == ["inside"]

    # the certificate: the warnings (the loops set aside) and whether β corrected the loops, per axis
    (page,) = PdfReader(cert).pages
    text = " ".join(page.extract_text().split())
    assert "STATUS: WARNING" in text and "loop dut_l03 set aside: " in text, text
    assert f"Thermal correction {latin1(thermal)}" in text and "Operating point" not in text, text
