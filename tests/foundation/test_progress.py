"""Progress bars (rgse_daemon.progress): on a terminal's stderr only, never on stdout, never escape codes elsewhere;
the study's progress reports; the demo's mapping of engine events to its two bars."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import pty
import re
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from rgse_daemon.commands.demo import BarsView, PlainView, demo_view
from rgse_daemon.manifest import load_points_csv
from rgse_daemon.pipeline import calibration as cal_mod
from rgse_daemon.pipeline import selection, study
from rgse_daemon.procedures.events import Event
from rgse_daemon.progress import stage_progress, terminal_console

REPO = Path(__file__).resolve().parents[2]
ANSI = re.compile(r"\x1b[\[\]()>=?]")
#: Variables that make rich treat any stream as a terminal (or none): the runs here decide by the stream alone.
RICH_ENV = ("FORCE_COLOR", "NO_COLOR", "TTY_COMPATIBLE", "TTY_INTERACTIVE", "COLUMNS", "LINES", "TERM")
DEADLINE_S = 90.0


def cli_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in RICH_ENV}
    return {**env, "PYTHONUNBUFFERED": "1", **extra}


def run_on_terminal(argv: list[str], tmp_path: Path) -> tuple[int, str, str]:
    """``rgse ARGV`` with a pseudo-terminal as stderr (stdout to a file): (exit status, stdout, terminal text)."""
    out_file = tmp_path / "stdout.txt"
    master, slave = pty.openpty()
    with out_file.open("wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "rgse_daemon.cli", *argv], cwd=REPO, stdin=subprocess.DEVNULL,
                                stdout=out, stderr=slave, env=cli_env(TERM="xterm-256color", COLUMNS="120"))
    os.close(slave)
    chunks: list[bytes] = []
    deadline = time.monotonic() + DEADLINE_S
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.5)
            if not ready:
                continue
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: every writer of the terminal is gone
                break
            if not chunk:
                break
            chunks.append(chunk)
        else:
            proc.kill()
            pytest.fail(f"rgse {' '.join(argv)} did not finish within {DEADLINE_S:.0f} s")
    finally:
        os.close(master)
    status = proc.wait(timeout=30)
    return status, out_file.read_text(encoding="utf-8"), b"".join(chunks).decode("utf-8", "replace")


def run_piped(argv: list[str], **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rgse_daemon.cli", *argv], cwd=REPO, capture_output=True, text=True,
                          env=cli_env(**env), timeout=DEADLINE_S, check=False)


# --- the CLI ----------------------------------------------------------------------------------------------------------
def test_study_shows_bars_on_a_terminal_only(tmp_path, paper_dir) -> None:
    argv = ["study", "--points", str(paper_dir / "table1_calibration.csv")]
    status, out, terminal = run_on_terminal(argv, tmp_path)
    assert status == 0, terminal
    n = len(cal_mod.MODELS)
    assert study.STAGE_MODELS in terminal and f"{n}/{n}" in terminal and "100%" in terminal, terminal
    assert ANSI.search(terminal)  # drawn as a live display
    # stdout is the command's output as ever: the same as without a terminal, no escape codes
    piped = run_piped(argv, TERM="xterm-256color", FORCE_COLOR="1")  # a CI log that asks for colour: still no bars
    assert piped.returncode == 0, piped.stderr
    assert out == piped.stdout and "gain-linear" in out
    assert not ANSI.search(out)
    assert not ANSI.search(piped.stderr) and study.STAGE_MODELS not in piped.stderr, piped.stderr


def test_study_json_on_a_terminal_keeps_stdout_one_object(tmp_path, paper_dir) -> None:
    status, out, terminal = run_on_terminal(["study", "--points", str(paper_dir / "table1_calibration.csv"), "--json"],
                                            tmp_path)
    assert status == 0, terminal
    assert out.count("\n") == 1 and json.loads(out)["kind"] == "models"
    assert study.STAGE_MODELS in terminal


def test_stage_progress_off_a_terminal_is_none() -> None:
    with stage_progress(io.StringIO()) as progress:
        assert progress is None
    assert terminal_console(io.StringIO()) is None


# --- the pipeline's reports -------------------------------------------------------------------------------------------
def test_rank_models_is_evaluate_all_ranked(paper_dir) -> None:
    points = load_points_csv(paper_dir / "table1_calibration.csv")
    calls: list[tuple[str, int, int]] = []
    ranked = study.rank_models(points, 9.81, 1.025, lambda *a: calls.append(a))
    expected = sorted(selection.evaluate_all(points, 9.81, 1.025), key=lambda e: e.loo_mean_abs_err_pct)
    assert [e.method for e in ranked] == [e.method for e in expected]
    assert [e.loo_mean_abs_err_pct for e in ranked] == [e.loo_mean_abs_err_pct for e in expected]
    n = len(cal_mod.MODELS)
    assert calls == [(study.STAGE_MODELS, k, n) for k in range(1, n + 1)]


def test_run_study_reports_every_loop_and_combination(paper_dir) -> None:
    """A study on synthetic loops around Table 1's torques: the same rows with and without a progress reporter,
    which hears of each loop and each combination once, in order, up to the totals."""
    points = load_points_csv(paper_dir / "table1_calibration.csv")
    rng = np.random.default_rng(7)
    bias3, bias5 = 1320.46, 315.96
    loops = [[(t3 + bias3 + rng.normal(0, 5, 300), t5 + bias5 + rng.normal(0, 5, 300), 0.004) for _ in range(2)]
             for t3, t5 in zip(points.torque_a3_nm, points.torque_a5_nm, strict=True)]

    def to_points(raw3: np.ndarray, raw5: np.ndarray) -> cal_mod.CalibrationPoints:
        return dataclasses.replace(points, torque_a3_nm=raw3 - raw3[0], torque_a5_nm=raw5 - raw5[0])

    grid = study.StudyGrid(crop_sigmas=(2.0, None), filters=("moving_average", "median"), windows=(5, 50))
    calls: list[tuple[str, int, int]] = []
    with_bar = study.run_study(loops, to_points, grid, "gain-linear", progress=lambda *a: calls.append(a))
    without = study.run_study(loops, to_points, grid, "gain-linear")
    assert [r.to_dict() for r in with_bar] == [r.to_dict() for r in without] and len(without) == grid.size == 16
    n_loops = 2 * len(points)
    assert calls == ([(study.STAGE_LOOPS, k, n_loops) for k in range(1, n_loops + 1)]
                     + [(study.STAGE_COMBINATIONS, k, grid.size) for k in range(1, grid.size + 1)])


# --- rgse demo: engine events to bars ---------------------------------------------------------------------------------
def campaign_loop(point: int, loop: int, loops: int = 5) -> Event:
    return Event("loop", f"point {point + 1}/8 loop {loop}/{loops} done", step="loop", loop_index=loop,
                 loop_count=loops, data={"point_index": point, "robot_s": 0.1, "overhead_s": 0.01})


def test_demo_bars_follow_the_events() -> None:
    buf = io.StringIO()
    view = BarsView(Console(file=buf, force_terminal=True, width=120), campaign_loops=40, measurement_loops=10)
    campaign, measurement = (view.progress.tasks[i] for i in (0, 1))
    assert (campaign.total, measurement.total) == (40, 10) and not measurement.started

    view.event(Event("step", "point 3/8: 3 CB", step="point", data={"point_index": 2}))
    view.event(Event("confirm", "mount 3 CB (point 3/8) and confirm", data={"point_index": 2}))
    # every finished campaign loop advances the bar by one (a torsional point has loops in every CoG pose, so the
    # point index alone cannot say how far the campaign is); a step event moves nothing
    for point, loop in [(p, lp) for p in range(2) for lp in range(1, 6)] + [(2, lp) for lp in range(1, 5)]:
        view.event(campaign_loop(point, loop))
    assert campaign.completed == 14  # points 1 and 2 (5 loops each), then loop 4 of point 3
    view.event(Event("step", "point 4/8: 4 CB", step="point", data={"point_index": 3}))
    assert campaign.completed == 14
    for point, loop in [(2, 5)] + [(p, lp) for p in range(3, 8) for lp in range(1, 6)]:
        view.event(campaign_loop(point, loop))
    assert campaign.completed == 40 and campaign.finished

    view.event(Event("step", "moving to the measurement pose", step="measurement-pose"))
    assert not measurement.started
    view.event(Event("step", "loop 1/10", step="loop", loop_index=1, loop_count=10))
    assert measurement.started and measurement.completed == 0
    view.event(Event("loop", "loop 3/10 done", step="loop", loop_index=3, loop_count=10, eta_s=42.4))
    assert measurement.completed == 3 and measurement.fields["eta"] == "eta 0:00:42"
    view.event(Event("alarm", "interlock: A1 out of range", data={"watcher": "range"}))
    view.event(Event("result", "mass 107.312 kg ± 0.210 kg (k = 2)", step="result"))

    view.progress.console.print(view.progress.get_renderable())
    text = buf.getvalue()
    plain = ANSI.sub("", re.sub(r"\x1b\[[0-9;]*m", "", text))
    for line in ("  [confirm] mount 3 CB (point 3/8) and confirm", "  [alarm] interlock: A1 out of range",
                 "  [result] mass 107.312 kg ± 0.210 kg (k = 2)"):
        assert line in plain
    assert "[loop]" not in plain  # loops move the bars instead
    assert re.search(r"calibration campaign.*40/40.*100%", plain)
    assert re.search(r"in-line measurement.*3/10.*30%.*eta 0:00:42", plain)


def test_demo_off_a_terminal_prints_todays_lines(capsys) -> None:
    assert isinstance(demo_view(quiet=False, bars=True), PlainView)  # pytest's captured stderr is no terminal
    with demo_view(quiet=False, bars=True) as view:
        view.note("calibration campaign: 8 points x 5 loops")
        view.event(campaign_loop(1, 3))
        view.event(Event("confirm", "mount 1 CB (point 2/8) and confirm"))
        view.event(Event("step", "loop 1/10", step="loop", loop_index=1, loop_count=10))
    assert capsys.readouterr().err == ("calibration campaign: 8 points x 5 loops\n"
                                       "  [loop] point 2/8 loop 3/5 done\n"
                                       "  [confirm] mount 1 CB (point 2/8) and confirm\n")
    with demo_view(quiet=True, bars=True) as view:
        view.note("calibration campaign: 8 points x 5 loops")
        view.event(campaign_loop(1, 3))
    assert capsys.readouterr() == ("", "")
