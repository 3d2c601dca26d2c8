"""The interlock: the static check of KRL programs before a push (:mod:`rgse_daemon.safety.static`) and the runtime
monitor that watches the robot while a program runs (:mod:`rgse_daemon.safety.monitor`)."""

from rgse_daemon.safety.static import CheckContext, ProgramRefused, Violation, check_program, ensure_allowed

__all__ = ["CheckContext", "ProgramRefused", "Violation", "check_program", "ensure_allowed"]
