"""Regression tests of issue #17: programs that the static check allowed although a KR C4 runs them unsafely.

Every program starts with ``$VEL_AXIS[1..6] = 1.0`` (slow enough for T1 on every motion below) and then uses one
way in which the checker's arithmetic or reading of the program differed from the controller's. Each must be refused
by ``rgse krl check`` (exit 3, a reason naming a line of the program) and by the daemon's push check
(:func:`~rgse_daemon.procedures.programs.static_checker`, which raises an InterlockError).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import pytest

from rgse_daemon import cli
from rgse_daemon.config import Config
from rgse_daemon.controller import Snapshot
from rgse_daemon.errors import InterlockError
from rgse_daemon.krl.abstract import AbstractInterpreter
from rgse_daemon.procedures.programs import static_checker
from rgse_daemon.safety.static import MAX_LINE_CHARS, CheckContext, Violation, check_program
from tests.safety_static.test_watchdog_rule import ARM, ROUTINE

SLOW = "".join(f"  $VEL_AXIS[{i}] = 1.0\n" for i in range(1, 7))
#: The rest of a measurement-pose target, so that a motion changes A1 only.
REST = "A2 -90.0, A3 90.0, A4 0.0, A5 0.0, A6 0.0"


def program(decls: str, body: str) -> str:
    """The slow start, the controller-side watchdog armed (``rgse krl check`` and the push require it), ``body``."""
    return f"&ACCESS RVP\n&REL 1\nDEF bypass( )\n{decls}{SLOW}{ARM}{body}END\n\n{ROUTINE}"


# name -> the program; a refusal must name at least one line of what it adds to the slow start
BYPASSES: dict[str, str] = {
    # 1. REAL is 32-bit: 16777217.0 is 16777216.0 on the controller, so D = 0 there (100 %, A1 100 deg)
    "1_float32": (
        program(
            "  DECL REAL BIG\n  DECL REAL D\n",
            "  BIG = 16777217.0\n  D = BIG - 16777216.0\n  $VEL_AXIS[1] = 100.0 - D * 99.0\n"
            f"  PTP {{A1 100.0 - D * 100.0, {REST}}}\n",
        )
    ),
    "1_float32_speed_only": (
        program(
            "  DECL REAL BIG\n  DECL REAL D\n",
            "  BIG = 16777217.0\n  D = BIG - 16777216.0\n  $VEL_AXIS[1] = 100.0 - D * 99.0\n  PTP {A1 10.0}\n",
        )
    ),
    "1_float32_target_only": (
        program(
            "  DECL REAL BIG\n  DECL REAL D\n",
            "  BIG = 16777217.0\n  D = BIG - 16777216.0\n  PTP {A1 100.0 - D * 100.0}\n",
        )
    ),
    "1_float32_in_one_expression": (
        program("", "  $VEL_AXIS[1] = 100.0 - (16777217.0 - 16777216.0) * 99.0\n  PTP {A1 10.0}\n")
    ),
    # 2. a REAL assigned to an INT is rounded: N = 1, so the speed is 1 + 0.4 * 247.5 = 100 %
    "2_real_to_int_rounds": (
        program("  DECL INT N\n", "  N = 0.6\n  $VEL_AXIS[1] = 1.0 + (N - 0.6) * 247.5\n  PTP {A1 10.0}\n")
    ),
    "2_real_to_int_target": (program("  DECL INT N\n", "  N = 0.6\n  PTP {A1 (N - 0.6) * 250.0}\n")),
    # 3. division follows the declared type: R = 7 is 7.0, R / 2 = 3.5
    "3_real_division": (program("  DECL REAL R\n", f"  R = 7\n  PTP {{A1 (R / 2 - 3) * 200.0, {REST}}}\n")),
    "3_real_division_speed": (
        program("  DECL REAL R\n", "  R = 7\n  $VEL_AXIS[1] = (R / 2 - 3) * 200.0\n  PTP {A1 10.0}\n")
    ),
    # 4. a REAL FOR bound: 7 / 2 = 3.5 (a tie: refused), 7.2 / 2 = 3.6 rounds to 4 passes of 12 deg = 48 deg
    "4_real_for_bound_tie": (
        program("  DECL REAL R\n  DECL INT I\n", "  R = 7\n  FOR I = 1 TO R / 2\n    PTP_REL {A1 12.0}\n  ENDFOR\n")
    ),
    "4_real_for_bound_rounds": (
        program("  DECL REAL R\n  DECL INT I\n", "  R = 7.2\n  FOR I = 1 TO R / 2\n    PTP_REL {A1 12.0}\n  ENDFOR\n")
    ),
    # 5. a partial aggregate assignment keeps the other fields: P.A1 stays 100
    "5_partial_aggregate": (
        program(
            "  DECL E6AXIS P\n",
            f"  P = {{A1 100.0, {REST}}}\n  P = {{A2 -90.0}}\n  PTP P\n",
        )
    ),
    "5_partial_aggregate_typed": (
        program(
            "  DECL E6AXIS P\n",
            f"  P = {{E6AXIS: A1 100.0, {REST}}}\n  P = {{E6AXIS: A2 -90.0}}\n  PTP P\n",
        )
    ),
    "5_partial_aggregate_copy": program(
        "  DECL E6AXIS P\n  DECL E6AXIS Q\n",
        f"  P = {{A1 100.0, {REST}}}\n  Q = P\n  Q = {{A3 90.0}}\n  PTP Q\n",
    ),
    "5_partial_aggregate_e6pos": (
        program(
            "  DECL E6POS P\n",
            "  P = {X 1800.0, Y 0.0, Z 2000.0, A 0.0, B 90.0, C 0.0, S 2, T 0}\n  P = {Z 1900.0}\n  PTP P\n",
        )
    ),
    # 6. two nested FORs on one counter: the inner loop resets I, the outer one never ends
    "6_nested_for_same_counter": (
        program(
            "  DECL INT I\n",
            "  FOR I = 1 TO 3\n    FOR I = 1 TO 2\n      PTP_REL {A1 1.0}\n    ENDFOR\n"
            "    PTP_REL {A1 10.0}\n  ENDFOR\n",
        )
    ),
    "6_for_counter_assigned": (
        program("  DECL INT I\n", "  FOR I = 1 TO 3\n    I = 1\n    PTP_REL {A1 10.0}\n  ENDFOR\n")
    ),
    # 7. EXIT outside a loop: everything after it must still be checked, and the EXIT itself is refused
    "7_exit_outside_loop": (program("", "  EXIT\n  $VEL_AXIS[1] = 100.0\n  PTP {A1 100.0}\n")),
    "7_exit_in_if_outside_loop": (
        program("", "  IF TRUE THEN\n    EXIT\n  ENDIF\n  $VEL_AXIS[1] = 100.0\n  PTP {A1 10.0}\n")
    ),
    # 7. a lone CR after a comment: whether it ends the line on the controller is not known
    "7_lone_cr_after_comment": (
        program("", "  $VEL_AXIS[1] = 100.0\n  ; slow down\r  $VEL_AXIS[1] = 1.0\n  PTP {A1 10.0}\n")
    ),
    "7_lone_cr": (program("", "  PTP {A1 10.0}\r  PTP {A1 0.0}\n")),
    # 7. an ISO-8859-1 C1 control character (NEL, U+0085) in a comment: if the controller ends the line there, the
    # write after it runs; the check read it as part of the comment
    "7_nel_in_comment": (program("", "  ; slow down\x85  $VEL_AXIS[1] = 100.0\n  PTP {A1 10.0}\n")),
    "7_c1_control_in_comment": (program("", "  ; slow down\x9b  $VEL_AXIS[1] = 100.0\n  PTP {A1 10.0}\n")),
    # 7. $TRACE members other than the ones the daemon writes
    "7_trace_member": (program("", "  $TRACE.STATE = #T_END\n  PTP {A1 10.0}\n")),
    "7_trace_whole": (program("", "  $TRACE.OTHER = 1\n  PTP {A1 10.0}\n")),
    # 7. ASIN is not a KRL built-in
    "7_asin": (program("", "  PTP {A1 ASIN(0.5)}\n")),
    "7_atan": (program("", "  PTP {A1 ATAN(0.5)}\n")),
    # 8. numbers and expressions beyond what the check (or the controller) evaluates
    "8_huge_int": (program("  DECL INT N\n", "  N = " + "9" * 320 + "\n  PTP {A1 10.0}\n")),
    "8_huge_int_in_target": (program("", "  PTP {A1 " + "1" + "0" * 320 + "}\n")),
    "8_int_overflow": (program("  DECL INT N\n", "  N = 2147483647\n  N = N + 1\n  PTP {A1 N / 100000000 + 10}\n")),
    "8_for_counter_overflow": program(
        "  DECL INT I\n", "  FOR I = 2147483647 TO 2147483647\n    PTP_REL {A1 5.0}\n  ENDFOR\n"
    ),
    # more of the same kind: intermediates, ties, built-ins whose last bit is not documented
    "1_intermediate_precision": program("", "  PTP {A1 ((16777216.0 + 1.0) - 16777216.0) * 40.0}\n"),
    "2_real_to_int_tie": program("  DECL INT N\n", "  N = 0.5\n  $VEL_AXIS[1] = 1.0 + N * 99.0\n  PTP {A1 10.0}\n"),
    "7_abs_of_int": program("", "  PTP {A1 ABS(-7) / 2 * 20.0}\n"),
    "7_sin_last_bit": program("", "  PTP {A1 (SIN(30.0) - 0.5) * 1.0E9}\n"),
    "8_uninitialised_element": program("  DECL REAL A[2]\n", "  $VEL_AXIS[1] = A[2]\n  PTP {A1 10.0}\n"),
    "8_long_chain": (program("", "  $VEL_AXIS[1] = 1.0" + " + 0.0" * 3000 + "\n  PTP {A1 10.0}\n")),
    # 9. a REAL array index: the check rounded 1.6 to 2, the simulated controller truncates it to 1 (which one the
    # KR C4 does, or whether it stops, is not documented): axis 1 at 100 % while the check saw axis 2 there
    "9_real_index_vel_axis": program("", "  $VEL_AXIS[1.6] = 100.0\n  PTP {A1 10.0}\n"),
    "9_real_index_vel_axis_variable": program(
        "  DECL REAL X\n", "  X = 1.6\n  $VEL_AXIS[X] = 100.0\n  PTP {A1 10.0}\n"
    ),
    "9_real_index_own_array": program(
        "  DECL REAL A[2]\n",
        "  A[1] = 1.0\n  A[2] = 1.0\n  A[1.6] = 100.0\n  $VEL_AXIS[1] = A[1]\n  PTP {A1 10.0}\n",
    ),
    # 10. a partial aggregate assigned to a structure whose value is not known (the join of two branches): the check
    # took the fields left out as uninitialised (the axis stays), the controller keeps the ones a branch set (A5 100)
    "10_partial_aggregate_after_join": program(
        "  DECL E6AXIS P\n",
        f"  IF $IN[1] THEN\n    P = {{A1 0.0, {REST}}}\n  ELSE\n    P = {{A1 0.0, A2 -90.0, A3 90.0, A4 0.0, A5 100.0, "
        "A6 0.0}\n  ENDIF\n  P = {A1 10.0}\n  $VEL_AXIS[5] = 100.0\n  PTP P\n",
    ),
    "10_partial_aggregate_after_loop": program(
        "  DECL E6AXIS P\n  DECL INT I\n",
        f"  P = {{A1 0.0, {REST}}}\n  FOR I = 1 TO $OV_PRO\n    P.A5 = P.A5 + 1.0\n  ENDFOR\n  P = {{A1 10.0}}\n"
        "  $VEL_AXIS[5] = 100.0\n  PTP P\n",
    ),
    # 11. an external axis target: neither the check nor the simulator models E1..E6 (the cell has none); on a cell
    # that had one, it would move unverified
    "11_external_axis": program("", f"  PTP {{A1 10.0, {REST}, E1 1000.0}}\n"),
    "11_external_axis_variable": program("  DECL E6AXIS P\n", f"  P = {{A1 10.0, {REST}, E2 -5.0}}\n  PTP P\n"),
    # 12. a line longer than the controller's editor is known to read: if it cut the line, 100.0 - 99.0 became 100.0
    "12_long_line": program("", "  $VEL_AXIS[1] = 100.0" + " " * 300 + "- 99.0\n  PTP {A1 10.0}\n"),
}


def refusal_lines(src: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> set[int]:
    path = tmp_path / "bypass.src"
    path.write_bytes(src.encode("latin-1"))
    assert cli.main(["krl", "check", str(path)]) == 3
    out = capsys.readouterr().out.splitlines()
    assert out, "a refusal names its reasons"
    lines = set()
    for line in out:
        assert line.startswith(f"{path}:"), line
        lines.add(int(line[len(str(path)) + 1 :].split(":")[0]))
    return lines


@pytest.mark.parametrize("name", sorted(BYPASSES))
def test_cli_refuses_the_bypass(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = BYPASSES[name]
    lines = refusal_lines(src, tmp_path, capsys)
    first = src.replace("\r\n", "\n").split("\n").index(SLOW.splitlines()[-1]) + 2
    last = src.replace("\r", "\n").count("\n")
    assert any(first <= n <= last for n in lines), (first, last, lines)


@dataclass(frozen=True)
class _Program:
    name: str
    src_text: str
    dat_text: str | None = None


def _snapshot() -> Snapshot:
    return Snapshot(
        taken_at_s=0.0,
        read_duration_s=0.0,
        mode_op="T1",
        pro_state1="P_FREE",
        pro_name1="",
        axes_deg=(0.0, -90.0, 90.0, 0.0, 0.0, 0.0),
        pos_act=None,
        torques_nm=(None,) * 6,
        motor_temps_k=(None,) * 6,
        trace_state="T_END",
        peri_rdy=True,
        user_saf=True,
        stopmess=False,
        ov_pro_pct=100,
        load=None,
        brake_sig="000000",
        vel_act_m_s=0.0,
        rob_stopped=True,
    )


@pytest.mark.parametrize("name", sorted(BYPASSES))
def test_push_check_refuses_the_bypass(name: str) -> None:
    cfg = Config()
    check = static_checker(cfg.limits, cfg.measurement.payload_lever_max_m)
    with pytest.raises(InterlockError):
        check(_Program("bypass", BYPASSES[name]), _snapshot())


def test_the_slow_base_program_is_allowed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The programs above are refused for what they add, not for their common start."""
    path = tmp_path / "base.src"
    # (external axes at 0 and a line of the longest allowed length are fine: 11 and 12 are refused for more)
    long_comment = "  ; " + "x" * (MAX_LINE_CHARS - 4) + "\n"
    path.write_text(program("", f"  PTP {{A1 10.0, {REST}, E1 0.0}}\n{long_comment}  PTP {{A1 0.0}}\n"),
                    encoding="latin-1")
    assert cli.main(["krl", "check", str(path)]) == 0, capsys.readouterr().out
    cfg = Config()
    static_checker(cfg.limits, cfg.measurement.payload_lever_max_m)(
        _Program("base", path.read_text(encoding="latin-1")), _snapshot()
    )


# --- robust failure ---------------------------------------------------------------------------------------------------
SLOW_TO_CHECK = program(
    "  DECL INT I\n  DECL INT J\n  DECL INT N\n",
    "  N = 0\n  FOR I = 1 TO 1000\n    FOR J = 1 TO 1000\n      N = N + 1\n    ENDFOR\n  ENDFOR\n  PTP {A1 10.0}\n",
)


def test_a_check_over_its_time_budget_ends_by_itself_and_refuses() -> None:
    """The daemon runs the check in a worker thread: the check must end by itself (a thread cannot be killed)."""
    found: list[list[Violation]] = []
    ctx = CheckContext(start_axes_deg=(0.0, -90.0, 90.0, 0.0, 0.0, 0.0), time_budget_s=0.3)
    worker = threading.Thread(target=lambda: found.append(check_program(SLOW_TO_CHECK, None, ctx, "slow.src")))
    worker.start()
    worker.join(timeout=30.0)
    assert not worker.is_alive()
    assert [v.rule for v in found[0]] == ["COMPLEXITY"]
    assert found[0][0].line >= 14 and "0.3 s" in found[0][0].message


def test_an_internal_failure_of_the_check_is_a_refusal(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Fault injection: whatever goes wrong inside the check refuses the program (exit 3), it never crashes or
    allows."""

    def broken(*args: object) -> None:
        raise ValueError("injected fault")

    monkeypatch.setattr(AbstractInterpreter, "motion", broken)
    path = tmp_path / "any.src"
    path.write_text(program("", "  PTP {A1 10.0}\n"), encoding="latin-1")
    assert cli.main(["krl", "check", str(path)]) == 3
    assert "INTERNAL" in capsys.readouterr().out


# --- data-list values persist between runs ----------------------------------------------------------------------------
#: A data list's (non-GLOBAL) values are persistent on the controller: a run leaves what it wrote in the .dat, and the
#: next run (the operator resets and starts it again without a new push) begins with those values, not the pushed ones.
PERSISTENT: dict[str, tuple[str, str]] = {
    "counter": (
        program("", "  IF RUNS > 0 THEN\n    $VEL_AXIS[1] = 100.0\n  ENDIF\n  RUNS = RUNS + 1\n  PTP {A1 10.0}\n"),
        "DEFDAT bypass\n  DECL INT RUNS = 0\nENDDAT\n",
    ),
    "pose": (
        program("", "  P = {A1 10.0}\n  $VEL_AXIS[5] = 100.0\n  PTP P\n  P = {A5 100.0}\n"),
        f"DEFDAT bypass\n  DECL E6AXIS P = {{A1 0.0, {REST}}}\nENDDAT\n",
    ),
}


@pytest.mark.parametrize("name", sorted(PERSISTENT))
def test_a_data_list_value_the_program_writes_is_not_known_at_its_start(name: str) -> None:
    src, dat = PERSISTENT[name]
    ctx = CheckContext(start_axes_deg=(0.0, -90.0, 90.0, 0.0, 0.0, 0.0))
    found = check_program(src, dat, ctx, "bypass.src")
    assert any(v.line > 9 for v in found), found  # a line after the slow start
    cfg = Config()
    with pytest.raises(InterlockError):
        static_checker(cfg.limits, cfg.measurement.payload_lever_max_m)(_Program("bypass", src, dat), _snapshot())


def test_a_data_list_value_the_program_only_reads_stays_known() -> None:
    """What the program never writes keeps the pushed value: a constant from the .dat still counts as one."""
    src = program("", "  IF FAST THEN\n    $VEL_AXIS[1] = 100.0\n  ENDIF\n  PTP {A1 10.0}\n")
    dat = "DEFDAT bypass\n  DECL BOOL FAST = FALSE\nENDDAT\n"
    assert check_program(src, dat, CheckContext(start_axes_deg=(0.0, -90.0, 90.0, 0.0, 0.0, 0.0)), "bypass.src") == []
