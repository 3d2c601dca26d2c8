"""The static check: one refused example per rule, allowed counterparts, and the ``rgse krl`` command line."""

from __future__ import annotations

from pathlib import Path

import pytest

from rgse_daemon import cli
from rgse_daemon.config import LimitsConfig
from rgse_daemon.errors import InterlockError, KrlSyntaxError
from rgse_daemon.krl.render import cube_corners
from rgse_daemon.safety.static import CheckContext, ProgramRefused, check_program, ensure_allowed
from tests.safety_static.test_watchdog_rule import ARM, ROUTINE

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
CTX = CheckContext(start_axes_deg=MEAS, payload_mass_kg=100.0, payload_cog_flange_m=(0.0, 0.0, 0.2))
SLOW = "\n".join(f"  $VEL_AXIS[{i}] = 2\n  $ACC_AXIS[{i}] = 20" for i in range(1, 7))


def program(body: str, decls: str = "") -> str:
    return f"&ACCESS RVP\n&REL 1\nDEF prop( )\n{decls}{SLOW}\n{body}\nEND\n"


def rules(src: str, ctx: CheckContext = CTX, dat: str | None = None) -> set[str]:
    return {v.rule for v in check_program(src, dat, ctx, "prop.src")}


ALLOWED = program(
    "  RGSE_STEP = 1\n  PTP {E6AXIS: A1 0, A2 -90, A3 100, A4 0, A5 10, A6 0}\n  PTP_REL {A3 -10, A5 -10}"
)


def armed(src: str) -> str:
    """``src`` with the controller-side watchdog armed before its first statement after the settings (what
    ``rgse krl check`` requires by default, tests/safety_static/test_watchdog_rule.py)."""
    return src.replace(SLOW + "\n", SLOW + "\n" + ARM, 1) + "\n" + ROUTINE


def test_a_slow_program_in_t1_is_allowed() -> None:
    assert check_program(ALLOWED, None, CTX) == []
    ensure_allowed(ALLOWED, None, CTX)
    aut = CheckContext(start_axes_deg=MEAS, mode="#AUT", area_cleared=True, key_confirmed=True)
    assert check_program(ALLOWED, None, aut) == []


@pytest.mark.parametrize(
    ("ctx", "rule"),
    [
        (CheckContext(start_axes_deg=MEAS, mode="AUT", area_cleared=False, key_confirmed=True), "MODE"),
        (CheckContext(start_axes_deg=MEAS, mode="AUT", area_cleared=True, key_confirmed=False), "MODE"),
        (CheckContext(start_axes_deg=MEAS, mode="T2", area_cleared=True, key_confirmed=True), "MODE"),
        (CheckContext(start_axes_deg=MEAS, mode="#EX", area_cleared=True, key_confirmed=True), "MODE"),
        (CheckContext(start_axes_deg=MEAS, payload_mass_kg=700.0), "PAYLOAD"),
        (CheckContext(start_axes_deg=None), "START_UNKNOWN"),
        (CheckContext(start_axes_deg=(60.0, -90.0, 90.0, 0.0, 0.0, 0.0)), "A1_ENVELOPE"),
    ],
)
def test_context_rules_refuse(ctx: CheckContext, rule: str) -> None:
    assert rule in rules(ALLOWED, ctx)


@pytest.mark.parametrize(
    ("body", "rule"),
    [
        ("  $VEL_AXIS[3] = 100\n  PTP {A3 120}", "SPEED"),  # too fast for the 200 mm/s of T1
        ("  PTP {E6AXIS: A1 50, A2 -90, A3 90, A4 0, A5 0, A6 0}", "A1_ENVELOPE"),
        ("  PTP {A2 25}", "JOINT_LIMIT"),
        ("  PTP_REL {A3 60}", "JOINT_LIMIT"),  # relative: 90 + 60 > 144 from the previous target
        ("  PTP {POS: X 1800, Y 0, Z 2000, A 0, B 90, C 0}", "CARTESIAN"),
        ("  PTP {X 1800, Y 0, Z 2000}", "CARTESIAN"),
        ("  OTHER_FLAG = TRUE", "WRITE"),
        ("  $TOOL = {X 0, Y 0, Z 100}", "SYSVAR"),
        ("  $VEL.ORI1 = 100", "SYSVAR"),
        ("  $OV_PRO = 150", "OV_PRO"),
        ("  $OV_PRO = RGSE_OV", "OV_PRO"),
        ("  $VEL_AXIS[3] = RGSE_SPEED", "VELOCITY"),  # the daemon could change it at any time
        ("  $VEL_AXIS[0] = 2", "VELOCITY"),
        # a near-zero speed: 85 deg at 2.3e-10 % never ends (found by the differential property test)
        ("  $VEL_AXIS[3] = 0.5 / 2147483647\n  PTP {A3 85}", "VELOCITY"),
        ("  $ACC_AXIS[5] = 0.001", "VELOCITY"),
        ("  PTP RGSE_TARGET", "TARGET"),  # a GLOBAL: not a constant
        ("  PTP $AXIS_ACT", "TARGET"),
        ("  PTP_REL {A3 -46, A5 -46}", "REL_AMPLITUDE"),
        ("  BAS(#INITMOV, 0)", "CALL"),
        ("  WAIT FOR my_check()", "CALL"),
        ("  LIN {A3 100}", "STATEMENT"),
        ("  PTP {A3 100} C_PTP", "STATEMENT"),
        ("  WHILE RGSE_GO\n    PTP_REL {A3 1}\n  ENDWHILE", "LOOP"),
        ("  LOOP\n    PTP_REL {A5 2}\n  ENDLOOP", "LOOP"),
    ],
)
def test_statement_rules_refuse(body: str, rule: str) -> None:
    found = check_program(program(body), None, CTX, "prop.src")
    assert rule in {v.rule for v in found}, found
    v = next(v for v in found if v.rule == rule)
    assert v.line >= 4 and v.column >= 1 and v.message


def test_heavy_payload_far_out_breaks_the_a5_torque() -> None:
    ctx = CheckContext(start_axes_deg=MEAS, payload_mass_kg=600.0, payload_cog_flange_m=(0.0, 0.0, 0.5))
    assert "A5_TORQUE" in rules(ALLOWED, ctx)
    # pointing the flange down (A5 = 90) puts the CoG under the A5 axis: no torque there, but the way there passes
    # through every torque in between
    down = program("  PTP {A5 90}")
    assert "A5_TORQUE" in rules(down, ctx)


def test_speed_counts_the_payload_points() -> None:
    body = program("  PTP {A3 110, A5 20}")
    assert rules(body) == set()
    far = CheckContext(start_axes_deg=MEAS, payload_points_flange_m=tuple(cube_corners(2.5)))
    assert rules(body, far) == {"SPEED"}


def test_override_assignment_cannot_lower_the_speed_the_operator_can_raise() -> None:
    fast = program("  $OV_PRO = 5\n  $VEL_AXIS[3] = 40\n  PTP {A3 110}")
    assert "SPEED" in rules(fast)
    locked = CheckContext(start_axes_deg=MEAS, override_max_pct=5.0)  # the daemon knows the override is locked
    assert "SPEED" not in rules(fast, locked)


def test_worst_case_over_branches_and_loops() -> None:
    branch = program(
        "  IF RGSE_CMD == 1 THEN\n    $VEL_AXIS[3] = 60\n  ELSE\n    $VEL_AXIS[3] = 1\n  ENDIF\n  PTP {A3 110}"
    )
    assert "SPEED" in rules(branch)  # either branch may have run
    unrolled = program("  FOR i = 1 TO 3\n    PTP_REL {A3 10}\n  ENDFOR", "  DECL INT i\n")
    assert rules(unrolled) == set()
    too_far = program("  FOR i = 1 TO 6\n    PTP_REL {A3 10}\n  ENDFOR", "  DECL INT i\n")
    assert rules(too_far) == {"JOINT_LIMIT"}  # the sixth step reaches 150 > 144
    resident = program(
        "  LOOP\n    WAIT FOR RGSE_CMD <> 0\n    IF RGSE_CMD == 1 THEN\n      PTP {A3 100}\n    ELSE\n"
        "      PTP {A3 80, A5 0}\n      PTP_REL {A5 5}\n    ENDIF\n    IF RGSE_CMD == 99 THEN\n      EXIT\n    ENDIF\n"
        "    RGSE_CMD = 0\n  ENDLOOP\n  PTP {A3 90, A5 0}"
    )
    assert rules(resident) == set()  # absolute targets in every branch: the set of poses settles
    drifting = resident.replace("PTP {A3 80, A5 0}", "PTP {A3 80}")
    assert rules(drifting) == {"LOOP"}  # A5 creeps by 5 deg per pass: unbounded
    # without the reset at the end of each pass, WAIT FOR RGSE_CMD <> 0 passes at once the next time: the loop is
    # not paced by the host and moves without end
    unpaced = resident.replace("    RGSE_CMD = 0\n", "")
    assert unpaced != resident and rules(unpaced) == {"UNBOUNDED"}


def test_constant_targets_from_the_data_list_and_locals() -> None:
    dat = (
        "DEFDAT prop\n  DECL E6AXIS xmeas = {A1 0, A2 -90, A3 95, A4 0, A5 0, A6 0}\n  DECL GLOBAL E6AXIS xg = "
        "{A1 0, A2 -90, A3 95, A4 0, A5 0, A6 0}\nENDDAT\n"
    )
    assert rules(program("  PTP xmeas"), dat=dat) == set()
    assert rules(program("  PTP xg"), dat=dat) == {"TARGET"}
    local = program("  p = {A3 100, A5 5}\n  p.A3 = 95\n  PTP p", "  DECL E6AXIS p\n")
    assert rules(local) == set()
    # never assigned: its fields keep the axes where they are (or the controller stops on them): no motion either way
    assert rules(program("  PTP p", "  DECL E6AXIS p\n")) == set()
    assert rules(program("  PTP p", "  DECL E6POS p\n")) == {"CARTESIAN"}


def test_forbidden_keywords_are_refused_not_syntax_errors() -> None:
    src = program("  INTERRUPT DECL 3 WHEN $IN[1] DO stop_it()\n  TRIGGER WHEN DISTANCE=0 DELAY=0 DO x=1")
    found = check_program(src, None, CTX)
    assert {(v.rule, v.line) for v in found} >= {("STATEMENT", 17)}
    # an interrupt other than the controller-side watchdog's is refused by the WATCHDOG rule
    found = check_program(program("  INTERRUPT DECL 3 WHEN $IN[1] DO stop_it()"), None, CTX)
    assert ("WATCHDOG", 16) in {(v.rule, v.line) for v in found}
    with pytest.raises(KrlSyntaxError):
        check_program("DEF broken(\nEND\n", None, CTX)


def test_ensure_allowed_lists_the_violations() -> None:
    with pytest.raises(ProgramRefused) as info:
        ensure_allowed(program("  OTHER = 1\n  PTP {A1 90}"), None, CTX, "bad.src")
    assert isinstance(info.value, InterlockError)
    assert {v.rule for v in info.value.violations} == {"WRITE", "A1_ENVELOPE"}
    assert "bad.src:16:3: WRITE" in str(info.value)


def test_limits_come_from_the_config() -> None:
    strict = CheckContext(start_axes_deg=MEAS, limits=LimitsConfig(brake_release_max_deg=5.0, a1_range_deg=10.0))
    assert rules(program("  PTP_REL {A3 6}\n  PTP {A1 11}"), strict) == {"REL_AMPLITUDE", "A1_ENVELOPE"}


# --- command line -----------------------------------------------------------------------------------------------------
def test_cli_check_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.src"
    good.write_text(armed(ALLOWED).replace("\n", "\r\n"), encoding="latin-1")
    assert cli.main(["krl", "check", str(good)]) == 0
    assert "allowed" in capsys.readouterr().out
    bad = tmp_path / "bad.src"
    bad.write_text(armed(program("  OTHER = 1\n  PTP {A1 90}\n  $OV_PRO = 200")), encoding="latin-1")
    assert cli.main(["krl", "check", str(bad)]) == 3
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3 and all(line.startswith(f"{bad}:") for line in lines)
    assert [line.split(": ")[1] for line in lines] == ["WRITE", "A1_ENVELOPE", "OV_PRO"]
    broken = tmp_path / "broken.src"
    broken.write_text("DEF broken(\nEND\n", encoding="latin-1")
    assert cli.main(["krl", "check", str(broken)]) == 2
    assert cli.main(["krl", "check", str(tmp_path / "missing.src")]) == 2
    capsys.readouterr()
    template = Path(__file__).resolve().parents[2] / "krl" / "rgse_warmup.src"
    assert cli.main(["krl", "check", str(template)]) == 2
    assert "an unrendered template" in capsys.readouterr().err  # not a syntax error at its first placeholder


def test_cli_check_reads_the_dat_beside(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "prog.src").write_text(armed(program("  PTP xfar")), encoding="latin-1")
    (tmp_path / "prog.dat").write_text("DEFDAT prog\n  DECL E6AXIS xfar = {A1 80}\nENDDAT\n", encoding="latin-1")
    assert cli.main(["krl", "check", str(tmp_path / "prog.src")]) == 3
    assert "A1_ENVELOPE" in capsys.readouterr().out


def test_cli_render_writes_checked_programs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "rgse.toml"
    cfg.write_text("[measurement]\nwarmup_cycles = 2\nbrake_release_deg = 30.0\n", encoding="utf-8")
    out = tmp_path / "out"
    assert cli.main(["krl", "render", "--out", str(out), "--config", str(cfg)]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["rgse_globals.dat"]
        + [
            f"{n}.src"
            for n in (
                "rgse_meas_pose",
                "rgse_oper_pose",
                "rgse_cal_pose",
                "rgse_warmup",
                "rgse_brake_release",
                "rgse_resident",
            )
        ]
    )
    warm = (out / "rgse_warmup.src").read_bytes()
    assert b"\r\n" in warm and b"FOR cycle = 1 TO 2" in warm
    assert b"PTP_REL {A3 30.0, A5 30.0}" in (out / "rgse_brake_release.src").read_bytes()
    capsys.readouterr()
    for src in out.glob("*.src"):
        assert cli.main(["krl", "check", str(src), "--config", str(cfg)]) == 0


def test_the_smallest_axis_speed_the_renderer_uses_is_allowed() -> None:
    """The floor of $VEL_AXIS / $ACC_AXIS is the renderer's own smallest speed: what it renders, the check passes."""
    assert rules(program("  $VEL_AXIS[3] = 0.01\n  $ACC_AXIS[3] = 0.01\n  PTP {A3 89}")) == set()
    # (5 deg at 0.01 % of A3's 70 deg/s take 714 s: above limits.max_motion_s, refused for its time)
    assert rules(program("  $VEL_AXIS[3] = 0.01\n  $ACC_AXIS[3] = 0.01\n  PTP {A3 85}")) == {"MOTION_TIME"}
