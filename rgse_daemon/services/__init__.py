"""The daemon's standing jobs, each in its own module; :class:`rgse_daemon.app.Daemon` composes them.

- :mod:`.link`: keep the controller connected, probe it while idle, reconnect with backoff;
- :mod:`.admission`: one run at a time, and whether a run may start at all;
- :mod:`.signals`: the stack light and the daemon-level alarms;
- :mod:`.state`: the retained ``state`` message and the systemd watchdog.
"""
