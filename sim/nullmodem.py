"""A virtual null-modem cable: two pseudo-terminals joined back to back.

Each end is a real tty path that pyserial (and the gateway, the sim, mbpoll) opens like a
serial port, so RTU can be tried without hardware; bytes written to one end arrive at the
other. A pty ignores the baud rate: bus timing is not exercised. A thread copies between
the two masters until :meth:`PtyPair.close`.
"""

from __future__ import annotations

import os
import select
import threading
import tty


class PtyPair:
    """Open ``.a`` on one side (e.g. a server) and ``.b`` on the other."""

    def __init__(self) -> None:
        self._m1, self._s1 = os.openpty()
        self._m2, self._s2 = os.openpty()
        for fd in (self._s1, self._s2):
            tty.setraw(fd)
        self.a: str = os.ttyname(self._s1)
        self.b: str = os.ttyname(self._s2)
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._copy, name="pty-bridge", daemon=True)
        self._thread.start()

    def _copy(self) -> None:
        peer = {self._m1: self._m2, self._m2: self._m1}
        while True:
            ready, _, _ = select.select([self._m1, self._m2, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                view = memoryview(data)
                while view:
                    view = view[os.write(peer[fd], view) :]

    def close(self) -> None:
        """Stop the bridge and close every descriptor."""
        os.write(self._stop_w, b"x")
        self._thread.join(timeout=5)
        for fd in (self._m1, self._s1, self._m2, self._s2, self._stop_r, self._stop_w):
            os.close(fd)
