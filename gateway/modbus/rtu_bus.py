"""The RTU bus: :class:`RtuBus`, Modbus RTU framing on an RS-485 line (or pty).

The transport hooks of :class:`gateway.modbus.bus.Bus` for a serial line: t3.5 silences,
the late-reply guard after a timeout, unit-0 broadcasts with the drives' turnaround.
:class:`gateway.modbus.rtu_over_tcp.RtuOverTcpBus` reuses them on a TCP byte stream.
Its own module because the rules of a line without transaction ids are their own concern.
"""

from __future__ import annotations

import time

from .bus import Bus
from .frames import rtu_encode, rtu_response_length
from .serialline import RtuStream, SerialLine, SerialLineLost, T35Mode


class RtuBus(Bus):
    """An RS-485 line (or pty) with Modbus RTU framing, one transaction at a time.

    Before each request the line must have been quiet for t3.5 + ``min_silence_s``.
    After a request that may still be answered (it timed out, its transaction was cancelled,
    or it was a retry whose first attempt may answer twice), the next *different* request
    waits until ``timeout_s + late_guard_s`` (default guard: ``timeout_s``) after that
    request was sent, discarding whatever arrives, then for a quiet line: a late reply
    inside that window is dropped. One arriving even later is still checked against the
    new request (unit, function, byte count, echoed address and quantity) and dropped if
    it does not fit; a late reply of the very same shape after the guard is the one case
    RTU cannot tell, hence the guard. Retries of the same request are sent without the
    guard (a late answer to the first attempt is a correct answer to the retry). Unit 0 is
    broadcast: sent, no reply awaited, ``b""`` returned, and the next request waits
    ``turnaround_s`` (input meanwhile discarded) while the drives act on it.

    t3.5 is ``silence_s`` if given, else per ``t35`` (``"spec"``: 1.75 ms above 19200 baud;
    ``"exact"``: 3.5 characters at the baud rate). Silences are timed exactly (no rounding
    up to whole milliseconds, see :mod:`gateway.modbus.serialline`), and bytes arriving during
    one restart it.
    """

    def __init__(self, port: str, *, baudrate: int = 19200, bytesize: int = 8,
                 parity: str = "E", stopbits: float = 1, silence_s: float | None = None,
                 late_guard_s: float | None = None, t35: T35Mode = "spec",
                 serial_kwargs: dict[str, object] | None = None, **bus_kwargs: object) -> None:
        bus_kwargs.setdefault("name", port)
        super().__init__(**bus_kwargs)  # type: ignore[arg-type]
        self._use_line(SerialLine(port, baudrate=baudrate, bytesize=bytesize, parity=parity,
                                  stopbits=stopbits, silence_s=silence_s, t35=t35,
                                  **(serial_kwargs or {})), late_guard_s)

    def _use_line(self, line: RtuStream, late_guard_s: float | None) -> None:
        """Serve transactions on ``line`` (a serial port here; another byte stream in
        :class:`gateway.modbus.rtu_over_tcp.RtuOverTcpBus`)."""
        self.line = line
        self.late_guard_s = self.timeout_s if late_guard_s is None else late_guard_s
        self._hold_until_s = 0.0  # no new request before this (monotonic)
        self._last_send_s = 0.0

    @property
    def connected(self) -> bool:
        return self.line.is_open

    async def _open(self) -> None:
        line = self.line
        assert isinstance(line, SerialLine)
        try:
            line.open()
        except SerialLineLost as err:
            raise OSError(str(err)) from err
        self._opened()

    def _opened(self) -> None:
        self._hold_until_s = time.monotonic() + self.line.silence_s  # drop what was there

    async def _close(self) -> None:
        self.line.close()

    async def _prepare(self) -> None:
        gap_s = self.line.silence_s + self.min_silence_s
        dropped = self.line.discard()
        hold_s = self._hold_until_s - time.monotonic()
        if hold_s > 0:  # a late reply may still come: listen and drop it
            while hold_s > 0 and self.line.is_open:
                await self.line.wait_data(hold_s)
                dropped += self.line.discard()
                hold_s = self._hold_until_s - time.monotonic()
            dropped += await self.line.wait_quiet(gap_s, max_wait_s=self.timeout_s)
        elif gap_s > self.line.quiet_for_s():  # exact wait; noise restarts the silence
            dropped += await self.line.wait_quiet(gap_s, max_wait_s=max(self.timeout_s,
                                                                        2 * gap_s))
        if dropped:
            self.counters.dropped += 1
            self.line.garbage_bytes += dropped

    async def broadcast(self, pdu: bytes, units: list[int]) -> None:
        """One unit-0 frame on the line, no reply (every drive acts on it)."""
        self.counters.broadcasts += 1
        await self.transact(0, pdu)

    async def _send(self, unit_id: int, pdu: bytes) -> int | None:
        await self.line.write(rtu_encode(unit_id, pdu))
        self._last_send_s = time.monotonic()
        if unit_id == 0:  # the drives' turnaround: no request (nor reply) meanwhile
            self._hold_until_s = max(self._hold_until_s, self._last_send_s + self.turnaround_s)
        return None

    async def _recv_internal(self, timeout_s: float
                             ) -> tuple[int | None, int | None, bytes] | None:
        frame = await self.line.read_frame(rtu_response_length, timeout_s)
        if frame is None:
            return None
        return frame[0], None, frame[1:-2]

    def _after_timeout(self, final: bool) -> None:
        if final:  # the last request sent may still be answered until well after its timeout
            self._hold_until_s = self._last_send_s + self.timeout_s + self.late_guard_s

    def _extra_wait_s(self, pdu: bytes) -> float:
        return self.line.wire_time_s(len(pdu) + 3)

    def _no_reply_expected(self, unit_id: int) -> bool:
        return unit_id == 0
