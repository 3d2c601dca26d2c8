"""The static check's rule texts and places, pinned (issue #31 item 6: survivors of a sampled mutmut run on
``safety/static.py`` after the merge of session 16). An operator reads the rule, the line, the column and the
message of a refusal to find what to change; each is asserted here whole.

* The watchdog rule: every problem of every declaration is reported (not only the first), an INTERRUPT inside a
  block or after the first motion, and a motion before the watchdog is armed, each at its statement's column.
* A Cartesian motion says why it cannot be verified and what to use instead.
* A CR without LF is named as such; a control character just before a line's CR LF is still found.
* A program above the size the check reads is refused for the program as a whole (line 0).
"""

from __future__ import annotations

from rgse_daemon.safety.static import MAX_PROGRAM_BYTES, CheckContext, Violation, check_program

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
CTX = CheckContext(start_axes_deg=MEAS)
SLOW = "\n".join(f"  $VEL_AXIS[{i}] = 2\n  $ACC_AXIS[{i}] = 20" for i in range(1, 7))
#: Line of the first statement after the slow settings (3 header lines, 12 settings).
FIRST = 16
COND = "$TIMER_FLAG[16] OR $TIMER_STOP[16]"
ROUTINE = "\nDEF STOPIT( )\n  BRAKE\n  HALT\nEND\n"


def program(body: str) -> str:
    return f"&ACCESS RVP\n&REL 1\nDEF world( )\n{SLOW}\n{body}\nEND\n"


def rules(src: str, rule: str, ctx: CheckContext = CTX) -> list[Violation]:
    return [v for v in check_program(src, None, ctx, "world.src") if v.rule == rule]


def test_every_wrong_watchdog_declaration_is_reported_in_its_place() -> None:
    src = program(f"  INTERRUPT DECL 2 WHEN {COND} DO STOPIT( )\n  INTERRUPT DECL 3 WHEN {COND} DO STOPIT( )\n"
                  "  PTP {A3 91}") + ROUTINE
    assert rules(src, "WATCHDOG") == [
        Violation(FIRST, 3, "WATCHDOG", "only the watchdog's interrupt 1 may be declared"),
        Violation(FIRST + 1, 3, "WATCHDOG", "only the watchdog's interrupt 1 may be declared"),
    ]


def test_an_interrupt_inside_a_block_or_after_the_first_motion_is_refused_where_it_stands() -> None:
    inside = program(f"  IF TRUE THEN\n    INTERRUPT DECL 1 WHEN {COND} DO STOPIT( )\n  ENDIF\n  PTP {{A3 91}}")
    assert rules(inside + ROUTINE, "WATCHDOG") == [
        Violation(FIRST + 1, 5, "WATCHDOG", "INTERRUPT only at the top level of the main routine")]
    after = program("  PTP {A3 91}\n  INTERRUPT ON 1") + ROUTINE
    assert rules(after, "WATCHDOG") == [
        Violation(FIRST + 1, 3, "WATCHDOG",
                  "INTERRUPT after the first motion: the watchdog is declared and switched on before it")]


def test_a_motion_before_the_watchdog_is_armed_is_refused_at_the_motion() -> None:
    (v,) = rules(program("  PTP {A3 91}"), "WATCHDOG", CheckContext(start_axes_deg=MEAS, require_watchdog=True))
    assert (v.line, v.column) == (FIRST, 3)
    assert v.message.startswith(f"motion before the controller-side watchdog is armed: declare INTERRUPT 1 WHEN {COND}")


def test_a_cartesian_motion_says_why_and_what_to_use() -> None:
    (v,) = rules(program("  LIN {X 1000, Y 0, Z 1000, A 0, B 0, C 0}"), "STATEMENT")
    assert (v.line, v.column) == (FIRST, 3)
    assert "inverse kinematics (joint path, payload point speeds): use PTP with E6AXIS targets" in v.message


def test_a_cr_without_lf_is_named_and_a_control_character_before_cr_lf_is_found() -> None:
    lone_cr = program("  ;x\ry\n  PTP {A3 91}")
    assert rules(lone_cr, "LINE_END") == [
        Violation(FIRST, 5, "LINE_END", "a CR without LF: how the controller reads it is not known, refused")]
    crlf = program("  PTP {A3 91} ;\x01").replace("\n", "\r\n")
    assert rules(crlf, "LINE_END") == [Violation(
        FIRST, 16, "LINE_END", "control character '\\x01': how the controller reads it is not known, refused")]


def test_a_program_too_big_to_read_is_refused_as_a_whole() -> None:
    src = program("  PTP {A3 91}") + ";" + "x" * (MAX_PROGRAM_BYTES + 10) + "\n"
    assert rules(src, "COMPLEXITY") == [
        Violation(0, 0, "COMPLEXITY", f"program of {len(src)} characters, above the {MAX_PROGRAM_BYTES} the check "
                                      "reads: too big to verify")]
