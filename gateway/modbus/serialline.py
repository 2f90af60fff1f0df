"""A serial port driven by the asyncio loop, with RTU frame reception.

pyserial opens and configures the port (real UART, USB adapter or pty alike); reading is
``loop.add_reader`` on its non-blocking fd, so no thread and no polling. The frame and
timing half (:class:`RtuStream`) serves any fd: a TCP connection to a serial device server
reuses it (:mod:`gateway.modbus.rtu_over_tcp`). Frames are cut by
length and CRC (:func:`gateway.modbus.frames.find_rtu_frame`), by line silence for function codes
whose length is unknown, and stale fragments are discarded, so garbage never blocks the line.

Timing: asyncio's epoll selector rounds every timeout up to a whole millisecond, so a
0.3 ms silence would last 1 ms and the 1.75 ms t3.5 2 ms. Waits shorter than
:data:`PRECISE_BELOW_S` use a Linux timerfd watched by the loop (it wakes the loop at the
exact time, within the kernel's timer slack of ~50 µs, late never early); longer ones
(reply timeouts) and other platforms use ``loop.call_at``. No thread, no busy wait.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import ctypes.util
import logging
import os
import select
import sys
import termios
import time
from collections.abc import Callable
from typing import Literal

import serial

from .frames import find_rtu_frame

log = logging.getLogger(__name__)

MAX_BUFFER_BYTES = 1024  # beyond this the oldest bytes are garbage by construction
#: empty reads in a row after which a port that keeps reporting readable is taken as gone
#: (pyserial's rule for a disconnected device, which never reports a hang-up)
MAX_EMPTY_READS = 100
PRECISE_BELOW_S = 0.02  # waits shorter than this use the exact timer (when available)

T35Mode = Literal["spec", "exact"]


class SerialLineLost(OSError):
    """The port went away (unplugged adapter, closed pty) or could not be opened."""


def _hung_up(fd: int) -> bool:
    """True if the tty behind ``fd`` reports a hang-up or an error (USB adapter unplugged,
    the other end of a pty closed)."""
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    return any(ev & (select.POLLHUP | select.POLLERR | select.POLLNVAL)
               for _, ev in poller.poll(0))


def char_time_s(baudrate: int, bytesize: int = 8, parity: str = "E", stopbits: float = 1) -> float:
    """Wire time of one character: start bit, data bits, parity bit, stop bits."""
    bits = 1 + bytesize + (0 if parity == "N" else 1) + stopbits
    return bits / baudrate


def t35_s(baudrate: int, bytesize: int = 8, parity: str = "E", stopbits: float = 1,
          mode: T35Mode = "spec") -> float:
    """Inter-frame silence t3.5: 3.5 character times; with ``mode="spec"`` fixed at 1.75 ms
    above 19200 baud, as the Modbus spec recommends (``"exact"``: 3.5 characters at any
    rate, 0.30 ms at 115200 8N1, for drives that detect frames that fast)."""
    if mode not in ("spec", "exact"):
        raise ValueError(f"t3.5 mode must be 'spec' or 'exact', not {mode!r}")
    if baudrate > 19200 and mode == "spec":
        return 0.00175
    return 3.5 * char_time_s(baudrate, bytesize, parity, stopbits)


def _wake(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)


# -- an exact timer: timerfd (Linux), watched by the loop ------------------------------------

_CLOCK_MONOTONIC = 1
_TFD_TIMER_ABSTIME = 1


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [("it_interval", _Timespec), ("it_value", _Timespec)]


def _load_timerfd() -> tuple[Callable[[], int],
                             Callable[[int, float, _Itimerspec], None]] | None:
    """(create, arm at absolute monotonic time with a caller-owned scratch itimerspec;
    0 disarms) or None where unavailable."""
    if not sys.platform.startswith("linux"):
        return None
    if hasattr(os, "timerfd_create"):  # Python 3.13+
        def create_os() -> int:
            return os.timerfd_create(time.CLOCK_MONOTONIC,
                                     flags=os.TFD_NONBLOCK | os.TFD_CLOEXEC)

        def arm_os(fd: int, when: float, _spec: _Itimerspec) -> None:
            os.timerfd_settime_ns(fd, flags=os.TFD_TIMER_ABSTIME,
                                  initial=max(int(when * 1e9), 1) if when else 0)

        return create_os, arm_os
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        timerfd_create, timerfd_settime = libc.timerfd_create, libc.timerfd_settime
    except (OSError, AttributeError):
        return None
    timerfd_create.argtypes = [ctypes.c_int, ctypes.c_int]
    timerfd_settime.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Itimerspec),
                                ctypes.c_void_p]

    def create() -> int:
        fd = timerfd_create(_CLOCK_MONOTONIC, os.O_NONBLOCK | os.O_CLOEXEC)
        if fd < 0:
            raise OSError(ctypes.get_errno(), "timerfd_create failed")
        return fd

    def arm(fd: int, when: float, spec: _Itimerspec) -> None:
        value = spec.it_value
        value.tv_sec, value.tv_nsec = divmod(max(int(when * 1e9), 1), 1_000_000_000) \
            if when else (0, 0)
        if timerfd_settime(fd, _TFD_TIMER_ABSTIME, spec, None) < 0:
            raise OSError(ctypes.get_errno(), "timerfd_settime failed")

    return create, arm


_TIMERFD = _load_timerfd()


class ExactTimer:
    """Calls ``callback`` once at a monotonic time (``time.monotonic()``, = ``loop.time()``),
    never early; within ~50 µs for waits under :data:`PRECISE_BELOW_S` where a timerfd is
    available, else through ``loop.call_at`` (whole milliseconds on epoll). One pending
    call at a time: arming again replaces it."""

    def __init__(self, callback: Callable[[], None]) -> None:
        self._loop = asyncio.get_running_loop()
        self._callback = callback
        self._handle: asyncio.TimerHandle | None = None
        self._when = 0.0  # armed timerfd deadline; 0: not armed
        self._fd: int | None = None
        self._spec = _Itimerspec()  # scratch for the ctypes call, one per timer
        if _TIMERFD is not None:
            try:
                self._fd = _TIMERFD[0]()
                self._loop.add_reader(self._fd, self._fired)
            except (OSError, RuntimeError, NotImplementedError) as err:
                log.debug("timerfd unavailable, millisecond timers: %s", err)
                self._close_fd()

    def arm(self, when: float) -> None:
        self.cancel()
        if self._fd is not None and when - time.monotonic() < PRECISE_BELOW_S:
            try:
                _TIMERFD[1](self._fd, when, self._spec)  # type: ignore[index]  (replaces)
                self._when = when
                return
            except OSError as err:
                log.debug("timerfd: %s", err)
        self._handle = self._loop.call_at(when, self._call)

    def cancel(self) -> None:
        """Nothing is called until armed again. (The timerfd is not disarmed, a syscall
        per wait: an expiry of a cancelled deadline is read and ignored.)"""
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None
        self._when = 0.0

    def close(self) -> None:
        self.cancel()
        self._close_fd()

    def _close_fd(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._fd)
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None

    def _fired(self) -> None:
        assert self._fd is not None
        try:
            os.read(self._fd, 8)
        except OSError:  # BlockingIOError: disarmed or re-armed meanwhile
            return
        if not self._when or time.monotonic() < self._when:
            return  # an expiry of a deadline that was cancelled or replaced
        self._when = 0.0
        self._callback()

    def _call(self) -> None:
        self._handle = None
        self._callback()


class RtuStream:
    """RTU frames over a byte stream read with the loop's reader on a non-blocking fd: async
    write, buffered async frame reads, exactly timed silences. A serial port
    (:class:`SerialLine`) or a TCP connection to a serial device server
    (:class:`gateway.modbus.rtu_over_tcp.TcpRtuLine`) opens the fd and hands it to
    :meth:`_attach`; the line settings (those of the RS-485 side) time the silences.

    ``silence_s`` is the end-of-frame silence (default t3.5 from the line settings, per
    ``t35``: ``"spec"``, 1.75 ms above 19200 baud, or ``"exact"``, 3.5 characters; a pty
    ignores baud rate, so tests may pass a smaller value). ``stale_s`` is how long an
    incomplete frame may wait for its remaining bytes (USB adapters and TCP deliver in
    chunks) before it is discarded as a fragment.
    """

    kind = "line"  # for log messages

    def __init__(self, port: str, *, baudrate: int = 19200, bytesize: int = 8,
                 parity: str = "E", stopbits: float = 1, silence_s: float | None = None,
                 stale_s: float = 0.1, t35: T35Mode = "spec") -> None:
        self.port = port
        self.baudrate = baudrate
        self.char_time_s = char_time_s(baudrate, bytesize, parity, stopbits)
        if t35 == "spec":  # positional call: a start-up patch of t35_s (bench what-if) holds
            default_s = t35_s(baudrate, bytesize, parity, stopbits)
        else:
            default_s = t35_s(baudrate, bytesize, parity, stopbits, mode=t35)
        self.t35 = t35
        self.silence_s = default_s if silence_s is None else silence_s
        self.stale_s = max(stale_s, self.silence_s)
        self._fd: int | None = None
        self._buf = bytearray()
        self._waiter: asyncio.Future[None] | None = None  # wait_data: bytes, loss or timer
        self._timer: ExactTimer | None = None
        self.last_rx_s = 0.0  # time.monotonic() of the last byte received
        self.tx_end_s = 0.0  # estimated end of our last transmission on the wire
        self.garbage_bytes = 0
        self.spurious_wakeups = 0  # readable, then nothing to read (not a loss)
        self._empty_reads = 0  # in a row
        self.lost = False

    # ------------------------------------------------------------------ open/close

    @property
    def is_open(self) -> bool:
        return self._fd is not None and not self.lost

    def _attach(self, fd: int) -> None:
        """Start reading the freshly opened ``fd`` (made non-blocking)."""
        self._fd = fd
        os.set_blocking(self._fd, False)
        self._buf.clear()
        self._empty_reads = 0
        self.lost = False
        asyncio.get_running_loop().add_reader(self._fd, self._on_readable)
        if self._timer is None:
            self._timer = ExactTimer(self._on_timer)

    def close(self) -> None:
        """Close the port (idempotent); waiters wake up and see the line lost."""
        if self._fd is not None:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_reader(self._fd)
        self._release()
        self._fd = None
        self.lost = True
        if self._timer is not None:
            self._timer.close()
            self._timer = None
        self._wake_waiter()

    def _release(self) -> None:
        """Close what :meth:`_attach` was given (a hook)."""

    def _empty_read(self) -> None:
        """The fd was readable and gave nothing (a hook: a hang-up, or not)."""

    def _wake_waiter(self) -> None:
        waiter, self._waiter = self._waiter, None
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _on_timer(self) -> None:
        self._wake_waiter()

    def _on_readable(self) -> None:
        assert self._fd is not None
        try:
            data = os.read(self._fd, 4096)
        except BlockingIOError:
            return
        except OSError as err:  # EIO when the other side of a pty closes, ENXIO on unplug
            log.warning("%s %s lost: %s", self.kind, self.port, err)
            self.close()
            return
        if not data:
            self._empty_read()
            return
        self._empty_reads = 0
        self._buf += data
        if len(self._buf) > MAX_BUFFER_BYTES:
            drop = len(self._buf) - MAX_BUFFER_BYTES // 4
            self.garbage_bytes += drop
            del self._buf[:drop]
        self.last_rx_s = now = time.monotonic()
        if self.tx_end_s > now:
            # Bytes received while our own frame was (by estimate) still on the wire: on a
            # half-duplex line an answer starts only after it ended (an echo of our own
            # frame keeps last_rx_s moving to its end). On a pty, which has no wire time,
            # this drops the phantom wire time of our request from the silence count.
            self.tx_end_s = now
        self._wake_waiter()

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
        """Return when bytes arrive, the line is lost, or after ``timeout_s`` (exactly, not
        rounded up to a millisecond; see :class:`ExactTimer`)."""
        if timeout_s <= 0 or not self.is_open or self._timer is None:
            return
        self._wake_waiter()  # one waiter at a time (the line serves one transaction)
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiter = fut
        timer = self._timer
        timer.arm(time.monotonic() + timeout_s)
        try:
            await fut
        finally:
            if self._waiter is fut:
                self._waiter = None
            timer.cancel()

    async def wait_quiet(self, quiet_s: float, max_wait_s: float, *,
                         discard: bool = True) -> int:
        """Wait until the line has been quiet (nothing received or sent) for ``quiet_s``, at
        most ``max_wait_s``; with ``discard``, drop what arrives meanwhile.

        Returns the number of bytes discarded (late replies, noise).
        """
        deadline = time.monotonic() + max_wait_s
        dropped = self.discard() if discard else 0
        while self.is_open:
            remaining = quiet_s - self.quiet_for_s()
            if remaining <= 0:
                break
            left = deadline - time.monotonic()
            if left <= 0:
                log.warning("%s %s: line not quiet after %.3f s", self.kind, self.port,
                            max_wait_s)
                break
            await self.wait_data(min(remaining, left))
            if discard:
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
                    log.debug("%s %s: fragment discarded: %s", self.kind, self.port,
                              self._buf.hex())
                    self.garbage_bytes += self.discard()
            if deadline is not None and time.monotonic() >= deadline:
                return None
            await self.wait_data(max(wait, 0.0002))


class SerialLine(RtuStream):
    """One serial port (real UART, USB adapter or pty), opened and configured by pyserial;
    ``serial_kwargs`` go to ``serial.Serial``."""

    kind = "serial"

    def __init__(self, port: str, *, baudrate: int = 19200, bytesize: int = 8,
                 parity: str = "E", stopbits: float = 1, silence_s: float | None = None,
                 stale_s: float = 0.1, t35: T35Mode = "spec", **serial_kwargs: object) -> None:
        super().__init__(port, baudrate=baudrate, bytesize=bytesize, parity=parity,
                         stopbits=stopbits, silence_s=silence_s, stale_s=stale_s, t35=t35)
        self._settings = dict(baudrate=baudrate, bytesize=bytesize, parity=parity,
                              stopbits=stopbits, **serial_kwargs)
        self._serial: serial.Serial | None = None

    def open(self) -> None:
        """Open and configure the port; raise :class:`SerialLineLost` if it cannot be."""
        self.close()
        try:
            ser = serial.Serial(self.port, timeout=0, write_timeout=0, **self._settings)
        except (OSError, serial.SerialException, ValueError) as err:
            raise SerialLineLost(f"{self.port}: {err}") from err
        except termios.error as err:  # the port refuses a setting (an adapter, a pty)
            s = self._settings
            raise SerialLineLost(f"{self.port}: refuses {s['baudrate']} baud, "
                                 f"{s['bytesize']}{s['parity']}{s['stopbits']:g}: "
                                 f"{err.args[-1] if err.args else err}") from err
        self._serial = ser
        self._attach(ser.fileno())

    def _release(self) -> None:
        if self._serial is not None:
            with contextlib.suppress(Exception):
                self._serial.close()
        self._serial = None

    def _empty_read(self) -> None:
        # with VMIN=0 an empty read means "nothing there", not end of file
        assert self._fd is not None
        self._empty_reads += 1
        if _hung_up(self._fd) or self._empty_reads >= MAX_EMPTY_READS:
            log.warning("serial %s lost: hung up (ready to read, nothing to read)", self.port)
            self.close()
        else:  # a tty's wake-up without data (seen on ptys); keep the line
            self.spurious_wakeups += 1
