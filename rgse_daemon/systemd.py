"""systemd service notification (``sd_notify``) without a library: one datagram on ``$NOTIFY_SOCKET``.

``Type=notify`` units wait for ``READY=1``; with ``WatchdogSec=`` systemd kills and restarts the service unless it
sends ``WATCHDOG=1`` at least every ``$WATCHDOG_USEC``. The daemon pings from a task on its own event loop, and only
while its health check passes, so a blocked loop or a wedged component ends in a restart (architecture §6).
Outside systemd (no ``$NOTIFY_SOCKET``) every call is a no-op.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


class Notifier:
    """Sends state lines such as ``READY=1``, ``STATUS=...``, ``WATCHDOG=1``, ``STOPPING=1`` to systemd."""

    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        # An abstract socket is written with a leading '@' in the environment and a NUL on the wire.
        self._address = ("\0" + address[1:]) if address.startswith("@") else address
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        watchdog_for_us = not pid or pid == str(os.getpid())
        self.watchdog_interval_s: float | None = (
            int(usec) / 1e6 / 2.0 if usec.isdigit() and int(usec) > 0 and watchdog_for_us else None
        )
        """Half the watchdog timeout, as sd_watchdog_enabled(3) recommends; ``None`` when no watchdog is set."""
        self._failed_once = False

    @property
    def enabled(self) -> bool:
        return bool(self._address)

    def notify(self, *lines: str) -> bool:
        """Send the lines as one datagram; returns whether it was sent. Never raises: systemd is advisory here."""
        if not self._address:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
                sock.sendto("\n".join(lines).encode(), self._address)
        except OSError as exc:
            if not self._failed_once:  # log a distinct error once
                log.warning("sd_notify to %r failed: %s", self._address, exc)
                self._failed_once = True
            return False
        return True

    def ready(self, status: str) -> bool:
        return self.notify("READY=1", f"STATUS={status}")

    def status(self, status: str) -> bool:
        return self.notify(f"STATUS={status}")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")
