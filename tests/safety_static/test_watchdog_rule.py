"""The static check's WATCHDOG rule: the daemon's controller-side watchdog is allowed (an interrupt whose routine
only stops the robot), every other interrupt, an interrupt routine that moves or calls, BRAKE outside it, switching
it off, and (when required) a motion before it is armed are refused."""

from __future__ import annotations

import pytest

from rgse_daemon.commands.krl import default_context
from rgse_daemon.config import Config
from rgse_daemon.errors import KrlSyntaxError
from rgse_daemon.safety.static import CheckContext, check_program

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
REQUIRED = CheckContext(start_axes_deg=MEAS, require_watchdog=True)
SLOW = "\n".join(f"  $VEL_AXIS[{i}] = 2\n  $ACC_AXIS[{i}] = 20" for i in range(1, 7))
ARM = """  INTERRUPT DECL 1 WHEN $TIMER_FLAG[16] OR $TIMER_STOP[16] DO WD( )
  INTERRUPT ON 1
  WAIT FOR NOT ($TIMER_FLAG[16] OR $TIMER_STOP[16])
"""
ROUTINE = """DEF WD( )
  BRAKE
  RGSE_WD_TRIP = TRUE
  WHILE $TIMER_FLAG[16] OR $TIMER_STOP[16]
    HALT
  ENDWHILE
END
"""
MOVE = "  PTP {A3 95}\n"


def program(head: str = ARM, body: str = MOVE, routine: str = ROUTINE) -> str:
    return f"DEF prop( )\n{SLOW}\n{head}{body}END\n\n{routine}"


def found(src: str, ctx: CheckContext = REQUIRED) -> set[tuple[str, int]]:
    return {(v.rule, v.line) for v in check_program(src, None, ctx, "prop.src")}


def test_the_watchdog_is_allowed_and_satisfies_the_requirement() -> None:
    assert found(program()) == set()
    assert found(program(routine=ROUTINE.replace("  BRAKE\n", "  BRAKE F\n"))) == set()


def test_a_motion_before_the_watchdog_is_armed_is_refused_when_required() -> None:
    assert found(program(head="", routine="")) == {("WATCHDOG", 14)}
    assert found(program(head="", routine=""), CheckContext(start_axes_deg=MEAS)) == set()  # not required
    # declared and on, but nothing waits for a fresh heartbeat: refused
    no_wait = ARM.split("\n")[:2]
    assert ("WATCHDOG", 16) in found(program(head="\n".join(no_wait) + "\n"))
    # armed after the motion: refused
    assert ("WATCHDOG", 14) in found(program(head="", body=MOVE + ARM))
    # the motion inside an IF before arming counts too
    assert ("WATCHDOG", 14) in found(program(head="", body="  IF RGSE_ARG == 1 THEN\n  " + MOVE + "  ENDIF\n" + ARM))


@pytest.mark.parametrize(
    "routine",
    [
        ROUTINE.replace("  BRAKE\n", "  BRAKE\n  PTP {A3 100}\n"),  # moves
        ROUTINE.replace("  BRAKE\n", "  BRAKE\n  PTP_REL {A1 5}\n"),
        ROUTINE.replace("    HALT\n", "    IF RGSE_ARG == 2 THEN\n      PTP {A3 100}\n    ENDIF\n"),  # moves, nested
        ROUTINE.replace("  BRAKE\n", "  BRAKE\n  OTHER( )\n"),  # calls
        ROUTINE.replace("  BRAKE\n", "  BRAKE\n  $OV_PRO = 100\n"),  # a system variable
        ROUTINE.replace("  BRAKE\n", "  BRAKE\n  $TIMER[16] = -1000\n"),  # feeds the watchdog itself
        ROUTINE.replace("  BRAKE\n", "  BRAKE\n  WAIT SEC 1\n"),
        ROUTINE.replace("DEF WD( )", "DEF WD(X:IN)\n  DECL INT X"),
        ROUTINE.replace("  BRAKE\n", ""),  # does not stop the motion
        ROUTINE.replace("  BRAKE\n", "  RGSE_WD_TRIP = TRUE\n  BRAKE\n"),  # not at once
        ROUTINE.replace("    HALT\n", "    RGSE_WD_TRIP = TRUE\n"),  # never halts
    ],
)
def test_an_interrupt_routine_that_does_more_than_stop_is_refused(routine: str) -> None:
    assert "WATCHDOG" in {r for r, _ in found(program(routine=routine))}


@pytest.mark.parametrize(
    "head",
    [
        ARM.replace("DECL 1 ", "DECL 4 ").replace("ON 1", "ON 4"),  # another interrupt number
        ARM.replace("$TIMER_FLAG[16] OR $TIMER_STOP[16] DO", "$TIMER_FLAG[16] DO"),  # a stopped timer never trips
        ARM.replace("$TIMER_FLAG[16] OR $TIMER_STOP[16] DO", "$TIMER_FLAG[17] OR $TIMER_STOP[17] DO"),
        ARM.replace("WD( )", "NOWHERE( )"),  # no such routine
        ARM + "  INTERRUPT OFF 1\n",  # switched off again
        ARM + "  INTERRUPT DISABLE 1\n",
        ARM + ARM.split("\n")[0] + "\n",  # declared twice (a second DECL replaces the first, switched off)
        "  BRAKE\n" + ARM,  # BRAKE outside an interrupt routine
        "  IF RGSE_ARG == 1 THEN\n" + ARM + "  ENDIF\n",  # not at the top level
    ],
)
def test_other_interrupt_forms_are_refused(head: str) -> None:
    assert "WATCHDOG" in {r for r, _ in found(program(head=head))}
    assert "WATCHDOG" in {r for r, _ in found(program(head=head), CheckContext(start_axes_deg=MEAS))}


@pytest.mark.parametrize("twice", ["DEF WD( )\n  PTP {A3 100}\nEND\n\n" + ROUTINE,
                                   ROUTINE + "\nDEF WD( )\n  PTP {A3 100}\nEND\n"])
def test_a_routine_defined_twice_does_not_parse(twice: str) -> None:
    with pytest.raises(KrlSyntaxError, match="defined twice"):
        check_program(program(routine=twice), None, REQUIRED, "prop.src")


def test_an_unused_second_routine_is_still_refused() -> None:
    assert ("STATEMENT", 28) in found(program() + "\nDEF OTHER( )\n  PTP {A1 5}\nEND\n")


def test_the_daemon_and_the_cli_require_it_by_default() -> None:
    cfg = Config()
    assert cfg.controller.watchdog_required and default_context(cfg).require_watchdog
