"""A subscribed state: latest value, flags, and a history ring in numpy."""

import time
from typing import Optional, Union

import iceoryx2 as iox2
import numpy as np

from .abi import StateSample, Status
from .bus import Bus, connect, receive_copy
from .discovery import StateInfo, resolve
from .errors import BusError, Timeout

#: The dtype of :meth:`State.history`: one row per sample, the fields of :class:`StateSample`.
SAMPLE_DTYPE = np.dtype(
    [
        ("seq", np.uint64),
        ("tick", np.uint64),
        ("t_sample_ns", np.uint64),
        ("t_publish_ns", np.uint64),
        ("value", np.float64),
        ("status", np.uint32),
    ]
)


class State:
    """Subscribes to one state and keeps its newest ``history`` samples.

    ``State("right_leg/RKP", domain="minihubo")`` opens ``conductor/right_leg/RKP``. Samples
    queue in shared memory until :meth:`update` (called by every reader below) moves them into
    the ring, so reading costs nothing between reads; a reader slower than the queue
    (``queue`` samples, at most the owner's per-state buffer) loses the oldest, counted in
    :attr:`missed` from the gaps in ``seq``.

    >>> rkp = State("right_leg/RKP", domain="minihubo")
    >>> rkp.wait()          # the first sample (the service keeps the last one for new readers)
    >>> rkp.value, rkp.flags
    (0.6, <Status.SIMULATED: 64>)
    >>> rkp.history()["value"]   # numpy, oldest first
    """

    def __init__(
        self,
        name: str,
        domain: Union[None, str, Bus] = None,
        history: int = 1024,
        queue: Optional[int] = None,
    ):
        if history < 1:
            raise ValueError("history must be at least 1 sample")
        self.bus = connect(domain)
        #: The state's metadata (:class:`~conductor.StateInfo`).
        self.info: StateInfo = resolve(name, self.bus)
        try:
            self._service = (
                self.bus.node.service_builder(iox2.ServiceName.new(self.info.service_name))
                .publish_subscribe(StateSample)
                .open()
            )
            max_queue = self._service.static_config.subscriber_max_buffer_size
            depth = max(1, min(queue or max_queue, max_queue))
            self._port = self._service.subscriber_builder().buffer_size(depth).create()
        except Exception as e:
            raise BusError(f"subscribing to {self.info.qualified_name!r}: {e!r}") from e
        self._ring = np.zeros(history, dtype=SAMPLE_DTYPE)
        self._next = 0  # ring slot the next sample goes to
        self._len = 0
        self._last: Optional[StateSample] = None
        #: Samples overwritten in the queue before they were read (gaps in ``seq``).
        self.missed = 0
        #: Times the owner restarted (``seq`` went backwards).
        self.restarts = 0

    def __repr__(self) -> str:
        return f"State({self.info.qualified_name!r}, value={self.value!r}, flags={self.flags!r})"

    @property
    def name(self) -> str:
        """``subsystem/state``."""
        return self.info.qualified_name

    def update(self) -> int:
        """Moves every queued sample into the ring; returns how many there were."""
        n = 0
        while True:
            s = receive_copy(self._port, StateSample, repr(self.name))
            if s is None:
                return n
            if self._last is not None:
                if s.seq > self._last.seq + 1:
                    self.missed += s.seq - self._last.seq - 1
                elif s.seq <= self._last.seq:
                    self.restarts += 1
            self._ring[self._next] = (
                s.seq,
                s.tick,
                s.t_sample_ns,
                s.t_publish_ns,
                s.value,
                s.status,
            )
            self._next = (self._next + 1) % len(self._ring)
            self._len = min(self._len + 1, len(self._ring))
            self._last = s
            n += 1

    def wait(self, timeout: float = 2.0, poll: float = 0.001) -> StateSample:
        """Waits for at least one new sample (polling every ``poll`` s); returns the newest.
        Raises :class:`~conductor.Timeout`."""
        deadline = time.monotonic() + timeout
        while self.update() == 0:
            if time.monotonic() >= deadline:
                raise Timeout(f"no sample of {self.name!r} within {timeout} s")
            time.sleep(poll)
        assert self._last is not None
        return self._last

    @property
    def sample(self) -> Optional[StateSample]:
        """The newest sample (after :meth:`update`), or ``None`` before the first."""
        self.update()
        return self._last

    @property
    def value(self) -> Optional[float]:
        """The newest value in the state's units, or ``None`` before the first sample."""
        s = self.sample
        return None if s is None else s.value

    @property
    def flags(self) -> Status:
        """The newest sample's :class:`~conductor.Status` flags (empty before the first)."""
        s = self.sample
        return Status(0 if s is None else s.status)

    @property
    def age(self) -> Optional[float]:
        """Seconds since the newest sample was taken (``None`` before the first)."""
        s = self.sample
        return None if s is None else (time.monotonic_ns() - s.t_sample_ns) * 1e-9

    def __len__(self) -> int:
        return self._len

    def history(self, seconds: Optional[float] = None) -> np.ndarray:
        """The samples in the ring, oldest first, as a numpy structured array of
        :data:`SAMPLE_DTYPE` (a copy). ``seconds`` keeps those sampled within that long of the
        newest."""
        self.update()
        n, cap = self._len, len(self._ring)
        start = (self._next - n) % cap
        rows = np.concatenate([self._ring[start:], self._ring[:start]]) if n == cap else (
            self._ring[start : start + n].copy()
        )
        if seconds is not None and n:
            t_newest = rows["t_sample_ns"][-1]
            rows = rows[rows["t_sample_ns"] + np.uint64(seconds * 1e9) >= t_newest]
        return rows

    def times(self, seconds: Optional[float] = None) -> np.ndarray:
        """Sample times (s, ``CLOCK_MONOTONIC``) of :meth:`history`."""
        return self.history(seconds)["t_sample_ns"] * 1e-9

    def values(self, seconds: Optional[float] = None) -> np.ndarray:
        """Values of :meth:`history`."""
        return self.history(seconds)["value"].copy()

    def close(self) -> None:
        """Releases the subscriber (also done when the object is collected)."""
        self._port = None
        self._service = None
