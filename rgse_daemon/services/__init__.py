"""The daemon's standing jobs, each in its own module; :class:`rgse_daemon.app.Daemon` composes them.

- :mod:`.link`: keep the controller connected, probe it while idle, reconnect with backoff;
- :mod:`.admission`: one run at a time, and whether a run may start at all;
- :mod:`.signals`: the stack light and the daemon-level alarms;
- :mod:`.state`: the retained ``state`` message and the systemd watchdog;
- :mod:`.heartbeat`: the heartbeat of the controller-side watchdog;
- :mod:`.recovery`: what the daemon does on every connect before it admits a run (a run a dead daemon left, its
  trace files on the controller), and when a stop fails;
- :mod:`.console`: the operator's web console (``[console] enabled``).
"""
