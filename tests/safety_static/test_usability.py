"""Refusals lifted where the evaluator is certain (issue #17 §6), each with its unsafe counterpart still refused."""

from __future__ import annotations

import pytest

from rgse_daemon.safety.static import CheckContext, check_program

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
CTX = CheckContext(start_axes_deg=MEAS)
SLOW = "".join(f"  $VEL_AXIS[{i}] = 1.0\n" for i in range(1, 7))
POSE = "A2 -90.0, A3 90.0, A4 0.0, A5 0.0, A6 0.0"


def rules(decls: str, body: str) -> set[str]:
    src = f"DEF usable( )\n{decls}{SLOW}{body}END\n"
    return {v.rule for v in check_program(src, None, CTX, "usable.src")}


@pytest.mark.parametrize(
    ("decls", "safe", "unsafe", "rule"),
    [
        # a branch that cannot run is not checked as if it could
        (
            "",
            "  IF FALSE THEN\n    PTP {A1 80.0}\n  ENDIF\n",
            "  IF TRUE THEN\n    PTP {A1 80.0}\n  ENDIF\n",
            "A1_ENVELOPE",
        ),
        (
            "  DECL INT N\n",
            "  N = 2\n  IF N > 5 THEN\n    PTP {A1 80.0}\n  ELSE\n    PTP {A1 10.0}\n  ENDIF\n",
            "  N = 9\n  IF N > 5 THEN\n    PTP {A1 80.0}\n  ELSE\n    PTP {A1 10.0}\n  ENDIF\n",
            "A1_ENVELOPE",
        ),
        # a WHILE of relative moves bounded by a counter: 3 x 5 deg is fine, 10 x 5 deg leaves the envelope
        (
            "  DECL INT N\n",
            "  N = 0\n  WHILE N < 3\n    PTP_REL {A1 5.0}\n    N = N + 1\n  ENDWHILE\n",
            "  N = 0\n  WHILE N < 10\n    PTP_REL {A1 5.0}\n    N = N + 1\n  ENDWHILE\n",
            "A1_ENVELOPE",
        ),
        (
            "  DECL INT N\n",
            "  N = 0\n  REPEAT\n    PTP_REL {A1 5.0}\n    N = N + 1\n  UNTIL N >= 3\n",
            "  N = 0\n  REPEAT\n    PTP_REL {A1 5.0}\n    N = N + 1\n  UNTIL N >= 10\n",
            "A1_ENVELOPE",
        ),
        # array targets whose values are known
        (
            "  DECL E6AXIS PTS[2]\n  DECL INT I\n",
            f"  PTS[1] = {{A1 10.0, {POSE}}}\n  PTS[2] = {{A1 -10.0, {POSE}}}\n"
            "  FOR I = 1 TO 2\n    PTP PTS[I]\n  ENDFOR\n",
            f"  PTS[1] = {{A1 10.0, {POSE}}}\n  PTS[2] = {{A1 80.0, {POSE}}}\n"
            "  FOR I = 1 TO 2\n    PTP PTS[I]\n  ENDFOR\n",
            "A1_ENVELOPE",
        ),
        (
            "  DECL REAL A[3]\n",
            "  A[1] = 5.0\n  A[2] = A[1] * 2\n  PTP {A1 A[2]}\n",
            "  A[1] = 5.0\n  A[2] = A[1] * 20\n  PTP {A1 A[2]}\n",
            "A1_ENVELOPE",
        ),
        # the $TRACE members the daemon writes itself
        (
            "",
            '  $TRACE.NAME[] = "run_01"\n  $TRACE.MODE = #T_START\n  PTP {A1 10.0}\n',
            "  $TRACE.STATE = #T_END\n",
            "SYSVAR",
        ),
    ],
)
def test_lifted_where_certain(decls: str, safe: str, unsafe: str, rule: str) -> None:
    assert rules(decls, safe) == set()
    assert rule in rules(decls, unsafe)


def test_what_stays_refused_when_not_certain() -> None:
    # an element whose index is not known: the array as a whole becomes unknown
    assert "TARGET" in rules(
        "  DECL E6AXIS PTS[2]\n",
        f"  PTS[1] = {{A1 10.0, {POSE}}}\n  PTS[RGSE_ARG] = {{A1 80.0, {POSE}}}\n  PTP PTS[1]\n",
    )
    # a WHILE whose counter the daemon controls
    assert rules("", "  WHILE RGSE_ARG < 3\n    PTP_REL {A1 5.0}\n  ENDWHILE\n") & {"LOOP", "A1_ENVELOPE"}
    # an element read before it was written
    assert "UNSURE" in rules("  DECL REAL A[3]\n", "  PTP {A1 A[2]}\n")
