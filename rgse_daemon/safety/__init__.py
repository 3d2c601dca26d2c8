"""The interlock and the safety policy.

- :mod:`~rgse_daemon.safety.allowlist`: the controller variables the daemon may write;
- :mod:`~rgse_daemon.safety.inputs`: the safety inputs (area cleared, AUT permitted, E-stop) as the interlock sees them;
- :mod:`~rgse_daemon.safety.static`: the static check of KRL programs before a push;
- :mod:`~rgse_daemon.safety.monitor`: the runtime monitor that watches the robot while a program runs;
- :mod:`~rgse_daemon.safety.makesafe`: a stop that reaches the robot, kept at until a read-back confirms it;
- :mod:`~rgse_daemon.safety.latch`: a stop that could not be confirmed stays an alarm until an operator clears it.
"""
