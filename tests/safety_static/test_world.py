"""Issue #31: the static check knows the world the robot moves in (the cell, bounded motion, the mounted payload) and
its budget counts from the first byte. Each rule: a program it refuses, naming the line and the reason."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from rgse_daemon import cli
from rgse_daemon.config import BoxConfig, CellConfig, Config, config_from_mapping
from rgse_daemon.controller import Snapshot
from rgse_daemon.errors import InterlockError
from rgse_daemon.kinematics import joint_frames
from rgse_daemon.procedures.programs import static_checker
from rgse_daemon.safety.static import (
    MAX_PROGRAM_BYTES,
    CheckContext,
    Violation,
    check_program,
    mounted_payload,
)
from tests.safety_static.test_watchdog_rule import ARM, ROUTINE

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
SLOW = "\n".join(f"  $VEL_AXIS[{i}] = 2\n  $ACC_AXIS[{i}] = 20" for i in range(1, 7))
CTX = CheckContext(start_axes_deg=MEAS)
#: Line of the first statement after the slow start (3 header lines, optional decls, 12 settings).
FIRST = 16


def program(body: str, decls: str = "") -> str:
    return f"&ACCESS RVP\n&REL 1\nDEF world( )\n{decls}{SLOW}\n{body}\nEND\n"


def armed(src: str) -> str:
    """``src`` with the controller-side watchdog armed after the settings (what the push and ``rgse krl check``
    require by default, tests/safety_static/test_watchdog_rule.py)."""
    return src.replace(SLOW + "\n", SLOW + "\n" + ARM, 1) + "\n" + ROUTINE


def found(src: str, ctx: CheckContext = CTX) -> list[Violation]:
    return check_program(src, None, ctx, "world.src")


def rules(src: str, ctx: CheckContext = CTX) -> set[str]:
    return {v.rule for v in found(src, ctx)}


# --- the workspace ----------------------------------------------------------------------------------------------------
def test_a_pose_below_the_floor_is_refused_naming_line_and_point() -> None:
    """Within every axis range and the A1 envelope, but the flange 0.7 m below the base: into the floor of the
    paper's 600 mm frame."""
    floor_pose = (0.0, 20.0, 70.0, 0.0, 0.0, 0.0)
    assert joint_frames(floor_pose)[5, 2, 3] < -0.7  # the finding: this pose is 0.7 m under the base
    src = program("  PTP {A2 -60}\n  PTP {A2 20, A3 70}")
    ws = [v for v in found(src) if v.rule == "WORKSPACE"]
    assert [v.line for v in ws] == [FIRST + 1]
    assert "floor" in ws[0].message and "z = " in ws[0].message and "A1..A6 = (" in ws[0].message
    # the same motion with the floor configured 2 m further down is no longer a floor violation
    deep = CellConfig(floor_z_m=-3.0, walls=BoxConfig(min_m=(-9, -9, -3), max_m=(9, 9, 9)), keep_out=())
    assert "WORKSPACE" not in rules(src, CheckContext(start_axes_deg=MEAS, cell=deep))


def test_the_dut_box_is_checked_not_only_the_flange() -> None:
    """A tilt the flange alone survives, but the DuT's 1.5 m box below it reaches the floor."""
    src = program("  PTP {A2 -30, A3 120, A5 60}")
    small = CellConfig(payload_box_flange_m=BoxConfig(min_m=(-0.01, -0.01, 0.0), max_m=(0.01, 0.01, 0.01)))
    assert "WORKSPACE" not in rules(src, CheckContext(start_axes_deg=MEAS, cell=small))
    big = CellConfig(payload_box_flange_m=BoxConfig(min_m=(-1.0, -1.0, 0.0), max_m=(1.0, 1.0, 2.5)))
    ws = [v for v in found(src, CheckContext(start_axes_deg=MEAS, cell=big)) if v.rule == "WORKSPACE"]
    assert ws and ws[0].line == FIRST and "the payload box" in ws[0].message


def test_walls_and_keep_out_boxes() -> None:
    src = program("  PTP {A1 40}")
    assert "WORKSPACE" not in rules(src)
    wall = CellConfig(walls=BoxConfig(min_m=(-4.5, -1.0, -0.6), max_m=(4.5, 4.5, 5.0)))  # y > -1 m: A1 40 swings out
    ws = [v for v in found(src, CheckContext(start_axes_deg=MEAS, cell=wall)) if v.rule == "WORKSPACE"]
    assert ws and ws[0].line == FIRST and "cell.walls" in ws[0].message and "y = -" in ws[0].message
    # a keep-out box (a column of the cell) beside the measurement pose, on the way of A1 turning
    column = BoxConfig(min_m=(1.0, -2.0, 0.0), max_m=(2.0, -1.4, 3.0))
    boxed = CellConfig(keep_out=(column,))
    ws = [v for v in found(src, CheckContext(start_axes_deg=MEAS, cell=boxed)) if v.rule == "WORKSPACE"]
    assert ws and "keep-out box 1" in ws[0].message
    assert "WORKSPACE" not in rules(program("  PTP {A1 -40}"), CheckContext(start_axes_deg=MEAS, cell=boxed))


# --- bounded motion ---------------------------------------------------------------------------------------------------
def test_a_loop_without_exit_around_motions_is_refused() -> None:
    src = program("  LOOP\n    PTP {A3 100}\n    PTP {A3 90}\n  ENDLOOP")
    v = [x for x in found(src) if x.rule == "UNBOUNDED"]
    assert [x.line for x in v] == [FIRST] and "LOOP without a reachable EXIT" in v[0].message
    # the same loop without motions holds the program but moves nothing: not a motion-time matter
    assert "UNBOUNDED" not in rules(program("  LOOP\n    WAIT SEC 1\n  ENDLOOP"))


def test_a_while_whose_bound_cannot_be_proven_is_refused() -> None:
    src = program("  WHILE RGSE_CMD <> 99\n    PTP {A3 100}\n    PTP {A3 90}\n  ENDWHILE")
    assert [x.line for x in found(src) if x.rule == "UNBOUNDED"] == [FIRST]


def test_a_for_with_2_pow_31_passes_is_judged_by_its_duration() -> None:
    src = program("  FOR i = 1 TO 2147483646\n    PTP {A3 100}\n    PTP {A3 90}\n  ENDFOR", "  DECL INT i\n")
    v = [x for x in found(src) if x.rule == "MOTION_TIME" and x.line == FIRST + 1]
    assert v and "2147483646 passes" in v[0].message
    # a long but short-lived FOR (2000 passes of nothing, then one motion) is fine: duration, not pass count
    fine = program("  FOR i = 1 TO 2000\n    RGSE_LOOP = i\n  ENDFOR\n  PTP {A3 100}", "  DECL INT i\n")
    assert rules(fine) == set()
    # ... and 2000 passes of motion are too long at this speed (20 deg at 1.4 deg/s, each way)
    long = program("  FOR i = 1 TO 2000\n    PTP {A3 100}\n    PTP {A3 90}\n  ENDFOR", "  DECL INT i\n")
    assert rules(long) == {"MOTION_TIME"}


def test_a_short_unrolled_loop_adds_up_its_passes() -> None:
    once = program("  FOR i = 1 TO 3\n    PTP {A3 100}\n    PTP {A3 90}\n  ENDFOR", "  DECL INT i\n")
    assert rules(once) == set()
    limits = Config().limits.model_copy(update={"max_motion_s": 20.0})
    v = [x for x in found(once, CheckContext(start_axes_deg=MEAS, limits=limits)) if x.rule == "MOTION_TIME"]
    assert v and "limits.max_motion_s = 20" in v[0].message


@pytest.mark.parametrize("value", ["0", "0.4", "-1"])
def test_ov_pro_below_the_smallest_speed_is_refused(value: str) -> None:
    v = [x for x in found(program(f"  $OV_PRO = {value}\n  PTP {{A3 100}}")) if x.rule == "OV_PRO"]
    assert [x.line for x in v] == [FIRST] and "1..100" in v[0].message


def test_ov_pro_one_is_allowed_and_slows_the_time_bound() -> None:
    assert rules(program("  $OV_PRO = 1\n  PTP {A3 91}")) == set()
    # 10 deg at 1 % of 2 % of 70 deg/s: over 700 s
    assert rules(program("  $OV_PRO = 1\n  PTP {A3 100}")) == {"MOTION_TIME"}


def test_a_host_paced_loop_is_bounded_per_command() -> None:
    """The resident program's command loop: each pass waits for a host command, the pass's motions are bounded."""
    body = ("  LOOP\n    WAIT FOR RGSE_CMD <> 0\n    IF RGSE_CMD == 99 THEN\n      EXIT\n    ENDIF\n"
            "    PTP {A3 100}\n    PTP {A3 90}\n    RGSE_CMD = 0\n  ENDLOOP")
    assert rules(program(body)) == set()
    # the reset must make the wait's condition FALSE: RGSE_CMD = 1 lets the next pass move at once
    assert rules(program(body.replace("RGSE_CMD = 0", "RGSE_CMD = 1"))) == {"UNBOUNDED"}
    # a motion before the wait is not paced
    early = body.replace("    WAIT FOR", "    PTP {A3 95}\n    WAIT FOR")
    assert rules(program(early)) == {"UNBOUNDED"}
    # a variable the host does not write cannot pace
    own = body.replace("RGSE_CMD", "cmd")
    assert "UNBOUNDED" in rules(program(own, "  DECL INT cmd\n"))
    # one pass longer than the maximum is refused
    limits = Config().limits.model_copy(update={"max_motion_s": 5.0})
    assert "MOTION_TIME" in rules(program(body), CheckContext(start_axes_deg=MEAS, limits=limits))


# --- the payload ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Program:
    name: str
    src_text: str
    dat_text: str | None = None


def _snapshot() -> Snapshot:
    return Snapshot(taken_at_s=0.0, read_duration_s=0.0, mode_op="T1", pro_state1="P_FREE", pro_name1="",
                    axes_deg=MEAS, pos_act=None, torques_nm=(None,) * 6, motor_temps_k=(None,) * 6,
                    trace_state="T_END", peri_rdy=True, user_saf=True, stopmess=False, ov_pro_pct=100, load=None,
                    brake_sig="000000", vel_act_m_s=0.0, rob_stopped=True)


HEAVY_DUT = {"cell": {"dut_mass_kg": 450.0, "dut_cog_flange_m": [0.0, 0.0, 0.6]}}


def test_the_push_check_refuses_a_program_over_the_load_diagram_with_the_configured_dut() -> None:
    """Safe with an empty flange; with the configured DuT (450 kg, 0.6 m out: 450·9.81·0.89 = 3929 Nm in the
    measurement pose, above 3330 Nm) the push is refused."""
    src = armed(program("  PTP {A3 95, A5 5}\n  PTP {A3 90, A5 0}"))  # the watchdog armed, as the push requires
    empty = Config()
    static_checker(empty.limits, empty.measurement.payload_lever_max_m)(_Program("world", src), _snapshot())
    cfg = config_from_mapping(HEAVY_DUT)
    mass_kg, cog = mounted_payload(cfg)
    assert mass_kg == 450.0 and cog == (0.0, 0.0, 0.6)
    check = static_checker(cfg.limits, cfg.measurement.payload_lever_max_m, payload=mounted_payload(cfg),
                           cell=cfg.cell)
    with pytest.raises(InterlockError, match=r"world.src:\d+:3: A5_TORQUE"):
        check(_Program("world", src), _snapshot())


def test_the_daemon_wires_the_configured_payload_into_its_push_check(tmp_path: Path) -> None:
    from rgse_daemon.app import Daemon

    daemon = Daemon(config_from_mapping({**HEAVY_DUT, "paths": {"data_dir": str(tmp_path)}}))
    engine = daemon._make_engine(object())  # type: ignore[arg-type]
    with pytest.raises(InterlockError, match="A5_TORQUE"):
        engine.checker(_Program("world", armed(program("  PTP {A3 95, A5 5}"))), _snapshot())


def test_mounted_payload_adds_the_fixture_and_takes_the_worst_credible_dut() -> None:
    cfg = config_from_mapping({"measurement": {"fixture_mass_kg": 100.0},
                               "properties": {"fixture": {"cog_flange_m": [0.0, 0.0, 0.1]}},
                               "cell": {"dut_mass_kg": 100.0, "dut_cog_flange_m": [0.0, 0.0, 0.3]}})
    assert mounted_payload(cfg) == (200.0, pytest.approx((0.0, 0.0, 0.2)))
    assert mounted_payload(cfg, 300.0, (0.0, 0.0, 0.5)) == (400.0, pytest.approx((0.0, 0.0, 0.4)))
    worst_kg, worst_cog = mounted_payload(Config())
    assert worst_kg == Config().limits.max_payload_kg and worst_cog[2] > 0.0


def test_krl_check_takes_the_payload(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "world.src"
    path.write_text(armed(program("  PTP {A3 95, A5 5}")), encoding="latin-1")
    assert cli.main(["krl", "check", str(path)]) == 0, capsys.readouterr().out
    assert cli.main(["krl", "check", str(path), "--payload", "450", "--cog", "0", "0", "0.6"]) == 3
    out = capsys.readouterr().out
    assert "A5_TORQUE" in out and "WATCHDOG" not in out
    assert cli.main(["krl", "check", str(path), "--payload", "50", "--cog", "0", "0", "0.6"]) == 0
    cfg = tmp_path / "heavy.toml"
    cfg.write_text('[cell]\ndut_mass_kg = 450.0\ndut_cog_flange_m = [0.0, 0.0, 0.6]\n', encoding="utf-8")
    assert cli.main(["krl", "check", str(path), "--config", str(cfg)]) == 3
    assert cli.main(["krl", "check", str(path), "--payload", "nan"]) == 2


# --- the budget -------------------------------------------------------------------------------------------------------
def test_a_program_above_the_size_limit_is_refused_before_it_is_parsed(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    big = program("  RGSE_STEP = 1\n" * (MAX_PROGRAM_BYTES // 16 + 1))
    assert len(big) > MAX_PROGRAM_BYTES
    v = found(big)
    assert [x.rule for x in v] == ["COMPLEXITY"] and "too big" in v[0].message
    path = tmp_path / "big.src"
    path.write_text(big, encoding="latin-1")
    assert cli.main(["krl", "check", str(path)]) == 2
    assert "refused unread" in capsys.readouterr().err


def test_the_budget_counts_the_parse() -> None:
    """A program just under the size limit whose parse alone takes longer than a tiny budget: refused by the budget
    (COMPLEXITY), the check ends by itself."""
    src = program("  RGSE_STEP = 1 + 2 * 3 - 4\n" * (MAX_PROGRAM_BYTES // 30))
    t0 = time.monotonic()
    parse_only = check_program(src, None, CheckContext(start_axes_deg=MEAS), "w.src")
    parse_s = time.monotonic() - t0
    assert parse_only == []
    results: list[list[Violation]] = []
    ctx = CheckContext(start_axes_deg=MEAS, time_budget_s=parse_s / 50)
    worker = threading.Thread(target=lambda: results.append(check_program(src, None, ctx, "w.src")))
    worker.start()
    worker.join(timeout=60.0)
    assert not worker.is_alive()
    assert [v.rule for v in results[0]] == ["COMPLEXITY"]


def test_the_keep_out_test_is_exact_for_a_turned_box() -> None:
    """A cube turned 45° about z whose bounding box overlaps a keep-out box that the cube itself misses (its corner
    points away), and the same cube moved 0.1 m closer, which does reach in."""
    import numpy as np

    from rgse_daemon.safety.static import _box_hits_box

    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    half = np.array([0.5, 0.5, 0.5])
    lo, hi = np.array([0.6, 0.6, -1.0]), np.array([2.0, 2.0, 1.0])
    # the turned cube's corners lie 0.707 m out on the x and y axes, so its bounding box reaches the keep-out box
    # (from 0.6 m); its face towards (1, 1) lies at x + y = 0.707, the keep-out's nearest corner at x + y = 1.2
    assert not _box_hits_box(np.zeros(3), rot, half, lo, hi)
    assert _box_hits_box(np.array([0.5, 0.5, 0.0]), rot, half, lo, hi)
    assert _box_hits_box(np.zeros(3), np.eye(3), np.array([0.7, 0.7, 0.5]), lo, hi)
