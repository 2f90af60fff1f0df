"""A serial port driven by the asyncio loop, with RTU frame reception.

pyserial opens and configures the port (real UART, USB adapter or pty alike); reading is
``loop.add_reader`` on its non-blocking fd, so no thread and no polling. Frames are cut by
length and CRC (:func:`gateway.frames.find_rtu_frame`), by line silence for function codes
whose length is unknown, and stale fragments are discarded, so garbage never blocks the line.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import time
from collections.abc import Callable

import serial

from .frames import find_rtu_frame

log = logging.getLogger(__name__)

MAX_BUFFER_BYTES = 1024  # beyond this the oldest bytes are garbage by construction


class SerialLineLost(OSError):
    """The port went away (unplugged adapter, closed pty) or could not be opened."""


def char_time_s(baudrate: int, bytesize: int = 8, parity: str = "E", stopbits: float = 1) -> float:
    """Wire time of one character: start bit, data bits, parity bit, stop bits."""
    bits = 1 + bytesize + (0 if parity == "N" else 1) + stopbits
    return bits / baudrate


def t35_s(baudrate: int, bytesize: int = 8, parity: str = "E", stopbits: float = 1) -> float:
    """Inter-frame silence t3.5 (fixed 1.75 ms above 19200 baud, as the spec recommends)."""
    if baudrate > 19200:
        return 0.00175
    return 3.5 * char_time_s(baudrate, bytesize, parity, stopbits)


def _wake(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)


class SerialLine:
    """One serial port: open/close, async write, buffered async RTU frame reads.

    ``silence_s`` is the end-of-frame silence (default t3.5 from the line settings; a pty
    ignores baud rate, so tests may pass a smaller value). ``stale_s`` is how long an
    incomplete frame may wait for its remaining bytes (USB adapters deliver in chunks)
    before it is discarded as a fragment.
    """

    def __init__(self, port: str, *, baudrate: int = 19200, bytesize: int = 8,
                 parity: str = "E", stopbits: float = 1, silence_s: float | None = None,
                 stale_s: float = 0.1, **serial_kwargs: object) -> None:
        self.port = port
        self.baudrate = baudrate
        self._settings = dict(baudrate=baudrate, bytesize=bytesize, parity=parity,
                              stopbits=stopbits, **serial_kwargs)
        self.char_time_s = char_time_s(baudrate, bytesize, parity, stopbits)
        self.silence_s = t35_s(baudrate, bytesize, parity, stopbits) if silence_s is None \
            else silence_s
        self.stale_s = max(stale_s, self.silence_s)
        self._serial: serial.Serial | None = None
        self._fd: int | None = None
        self._buf = bytearray()
        self._event = asyncio.Event()
        self.last_rx_s = 0.0  # time.monotonic() of the last byte received
        self.tx_end_s = 0.0  # estimated end of our last transmission on the wire
        self.garbage_bytes = 0
        self.lost = False

    # ------------------------------------------------------------------ open/close

    @property
    def is_open(self) -> bool:
        return self._fd is not None and not self.lost

    def open(self) -> None:
        """Open and configure the port; raise :class:`SerialLineLost` if it cannot be."""
        self.close()
        try:
            ser = serial.Serial(self.port, timeout=0, write_timeout=0, **self._settings)
        except (OSError, serial.SerialException, ValueError) as err:
            raise SerialLineLost(f"{self.port}: {err}") from err
        self._serial = ser
        self._fd = ser.fileno()
        os.set_blocking(self._fd, False)
        self._buf.clear()
        self.lost = False
        asyncio.get_running_loop().add_reader(self._fd, self._on_readable)

    def close(self) -> None:
        """Close the port (idempotent); waiters wake up and see the line lost."""
        if self._fd is not None:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_reader(self._fd)
        if self._serial is not None:
            with contextlib.suppress(Exception):
                self._serial.close()
        self._serial = None
        self._fd = None
        self.lost = True
        self._event.set()

    def _on_readable(self) -> None:
        assert self._fd is not None
        try:
            data = os.read(self._fd, 4096)
        except BlockingIOError:
            return
        except OSError as err:  # EIO when the other side of a pty closes, ENXIO on unplug
            log.warning("serial %s lost: %s", self.port, err)
            self.close()
            return
        if not data:
            log.warning("serial %s lost: end of file", self.port)
            self.close()
            return
        self._buf += data
        if len(self._buf) > MAX_BUFFER_BYTES:
            drop = len(self._buf) - MAX_BUFFER_BYTES // 4
            self.garbage_bytes += drop
            del self._buf[:drop]
        self.last_rx_s = time.monotonic()
        self._event.set()

    # ------------------------------------------------------------------ write

    async def write(self, data: bytes) -> None:
        """Write all of ``data`` (waits for the fd to be writable if the driver is full)."""
        loop = asyncio.get_running_loop()
        view = memoryview(data)
        while view:
            if not self.is_open:
                raise SerialLineLost(f"{self.port}: closed")
            assert self._fd is not None
            try:
                written = os.write(self._fd, view)
            except BlockingIOError:
                fut: asyncio.Future[None] = loop.create_future()
                fd = self._fd
                loop.add_writer(fd, _wake, fut)
                try:
                    await asyncio.wait_for(fut, 1.0)
                except asyncio.TimeoutError as err:
                    raise SerialLineLost(f"{self.port}: write stalled") from err
                finally:
                    loop.remove_writer(fd)
                continue
            except OSError as err:
                self.close()
                raise SerialLineLost(f"{self.port}: {err}") from err
            view = view[written:]
        self.tx_end_s = time.monotonic() + len(data) * self.char_time_s

    # ------------------------------------------------------------------ read

    def wire_time_s(self, nbytes: int) -> float:
        """Time ``nbytes`` take on the wire at the configured settings."""
        return nbytes * self.char_time_s

    def quiet_for_s(self) -> float:
        """Time since the line last carried a byte (received or sent)."""
        return time.monotonic() - max(self.last_rx_s, self.tx_end_s)

    @property
    def pending_bytes(self) -> int:
        """Bytes received and not yet consumed."""
        return len(self._buf)

    def discard(self) -> int:
        """Drop buffered bytes; returns how many."""
        n = len(self._buf)
        self._buf.clear()
        return n

    async def wait_data(self, timeout_s: float) -> None:
        """Return when bytes arrive, the line is lost, or after ``timeout_s``."""
        if timeout_s <= 0:
            return
        self._event.clear()
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(self._event.wait(), timeout_s)

    async def wait_quiet(self, quiet_s: float, max_wait_s: float) -> int:
        """Discard input until the line has been quiet for ``quiet_s`` (at most ``max_wait_s``).

        Returns the number of bytes discarded (late replies, noise).
        """
        deadline = time.monotonic() + max_wait_s
        dropped = self.discard()
        while self.is_open:
            remaining = quiet_s - self.quiet_for_s()
            if remaining <= 0:
                break
            left = deadline - time.monotonic()
            if left <= 0:
                log.warning("serial %s: line not quiet after %.3f s", self.port, max_wait_s)
                break
            await self.wait_data(min(remaining, left))
            dropped += self.discard()
        return dropped

    async def read_frame(self, length_fn: Callable[[bytes], int | None],
                         timeout_s: float | None = None) -> bytes | None:
        """Next CRC-valid frame (unit id + PDU + CRC), or None after ``timeout_s``.

        Garbage before a frame is skipped; an incomplete frame older than ``stale_s`` and
        bytes that form no frame at silence are discarded (counted in ``garbage_bytes``).
        Raises :class:`SerialLineLost` if the port goes away.
        """
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            quiet = time.monotonic() - self.last_rx_s
            scan = find_rtu_frame(self._buf, length_fn, at_silence=quiet >= self.silence_s)
            if scan.consumed:
                self.garbage_bytes += scan.consumed - (len(scan.frame) if scan.frame else 0)
                del self._buf[:scan.consumed]
            if scan.frame is not None:
                return scan.frame
            if not self.is_open:
                raise SerialLineLost(f"{self.port}: closed")
            wait = 3600.0 if deadline is None else deadline - time.monotonic()
            if self._buf:
                if quiet < self.silence_s:
                    wait = min(wait, self.silence_s - quiet)
                elif quiet < self.stale_s:
                    wait = min(wait, self.stale_s - quiet)
                else:
                    log.debug("serial %s: fragment discarded: %s", self.port, self._buf.hex())
                    self.garbage_bytes += self.discard()
            if deadline is not None and time.monotonic() >= deadline:
                return None
            await self.wait_data(max(wait, 0.0002))
