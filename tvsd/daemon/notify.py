"""systemd's notify protocol (sd_notify(3)) without a dependency.

Under ``Type=notify`` systemd passes ``$NOTIFY_SOCKET``: a path, or an abstract-namespace name when
it starts with '@' (the '@' stands for a leading NUL byte). A notification is one datagram of
newline-separated ``KEY=value`` assignments: ``READY=1``, ``STATUS=...``, ``WATCHDOG=1``,
``STOPPING=1``. ``$WATCHDOG_USEC`` (with ``$WATCHDOG_PID`` naming the process it is meant for) asks
for ``WATCHDOG=1`` at least that often; sd_watchdog_enabled(3) recommends pinging at half of it.

Outside systemd (no ``$NOTIFY_SOCKET``) every call is a no-op returning False, so the daemon calls
them unconditionally. A failed send is logged once and never raised: a notification that cannot be
delivered must not take the scanner down (systemd's watchdog will act if the daemon is really stuck).
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger(__name__)


def socket_address(value: str) -> str | bytes | None:
    """The sendto() address for a $NOTIFY_SOCKET value, or None if it is not one we can use."""
    if value.startswith("@") and len(value) > 1:
        return b"\0" + value[1:].encode()  # abstract namespace: no file, leading NUL
    if value.startswith("/"):
        return value
    return None  # e.g. "vsock:..." (systemd ≥ 254, VMs): not supported here


def watchdog_usec(environ: Mapping[str, str], pid: int) -> int | None:
    """$WATCHDOG_USEC if it is meant for `pid` (sd_watchdog_enabled(3)), else None."""
    raw = environ.get("WATCHDOG_USEC", "")
    try:
        usec = int(raw)
    except ValueError:
        return None
    if usec <= 0:
        return None
    owner = environ.get("WATCHDOG_PID")
    if owner:
        try:
            if int(owner) != pid:
                return None  # inherited by a child: the watchdog belongs to the parent
        except ValueError:
            return None
    return usec


class Notifier:
    """Sends notifications to the service manager; inert when not started by systemd."""

    def __init__(self, environ: Mapping[str, str] | None = None, pid: int | None = None) -> None:
        env = os.environ if environ is None else environ
        raw = env.get("NOTIFY_SOCKET", "")
        self.address = socket_address(raw) if raw else None
        if raw and self.address is None:
            log.warning("NOTIFY_SOCKET=%r is not a path or @abstract name; systemd notify is off", raw)
        usec = watchdog_usec(env, os.getpid() if pid is None else pid)
        self.watchdog_usec = usec if self.address is not None else None
        self._sock: socket.socket | None = None
        self._warned = False

    @property
    def enabled(self) -> bool:
        return self.address is not None

    @property
    def watchdog_interval_s(self) -> float | None:
        """How often to call watchdog(): half of WatchdogSec, or None when there is no watchdog."""
        return None if self.watchdog_usec is None else self.watchdog_usec / 2e6

    def notify(self, *assignments: str) -> bool:
        """Send one datagram of KEY=value lines; True if it was sent."""
        if self.address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock.setblocking(False)  # never stall the event loop on a full manager queue
            self._sock.sendto("\n".join(assignments).encode(), self.address)
        except OSError as exc:
            if not self._warned:
                log.warning("systemd notify to %r failed: %s", self.address, exc)
                self._warned = True
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        return self.notify("READY=1", *([_status(status)] if status is not None else []))

    def status(self, text: str) -> bool:
        return self.notify(_status(text))

    def watchdog(self) -> bool:
        """Ping the watchdog; no-op unless systemd asked for one (WatchdogSec=)."""
        return self.watchdog_usec is not None and self.notify("WATCHDOG=1")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _status(text: str) -> str:
    # A newline would start a new assignment: systemd would read the rest as a bogus key.
    return "STATUS=" + " ".join(text.splitlines())
