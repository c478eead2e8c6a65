"""An executor's health: ``conductor/<subsystem>/stats``."""

import time
from typing import Optional, Union

import iceoryx2 as iox2
import numpy as np

from .abi import HISTOGRAM_BUCKETS, ExecutorStats, bucket_range
from .bus import Bus, connect, receive_copy, validate_name
from .errors import BusError, Timeout, UnknownSubsystem


class Stats:
    """Subscribes to an executor's :class:`~conductor.ExecutorStats` (published about 10 times
    a second: ticks, misses, lateness percentiles and histogram, setpoints rejected and
    clamped, watchdog trips, device health)."""

    def __init__(self, subsystem: str, domain: Union[None, str, Bus] = None):
        self.bus = connect(domain)
        self.subsystem = validate_name("subsystem", subsystem)
        name = f"conductor/{subsystem}/stats"
        try:
            self._service = (
                self.bus.node.service_builder(iox2.ServiceName.new(name))
                .publish_subscribe(ExecutorStats)
                .open()
            )
            self._port = self._service.subscriber_builder().create()
        except Exception as e:
            if "DoesNotExist" in repr(e):
                raise UnknownSubsystem(subsystem, self.bus.domain, name) from e
            raise BusError(f"subscribing to {name!r}: {e!r}") from e
        self._latest: Optional[ExecutorStats] = None

    def latest(self) -> Optional[ExecutorStats]:
        """The newest stats received so far (drains the queue), or ``None``."""
        while True:
            s = receive_copy(self._port, ExecutorStats, f"{self.subsystem!r} stats")
            if s is None:
                return self._latest
            self._latest = s

    def wait(self, timeout: float = 2.0, newer_than: int = -1) -> ExecutorStats:
        """Waits for stats whose ``seq`` is above ``newer_than``; raises
        :class:`~conductor.Timeout`."""
        deadline = time.monotonic() + timeout
        while True:
            s = self.latest()
            if s is not None and s.seq > newer_than:
                return s
            if time.monotonic() >= deadline:
                raise Timeout(f"no stats of {self.subsystem!r} within {timeout} s")
            time.sleep(0.005)


def histogram(stats: ExecutorStats) -> np.ndarray:
    """The lateness histogram as a numpy array of ``(low_ns, high_ns, count)`` rows."""
    rows = np.zeros(
        HISTOGRAM_BUCKETS, dtype=[("low_ns", np.uint64), ("high_ns", np.uint64), ("count", np.uint64)]
    )
    for i in range(HISTOGRAM_BUCKETS):
        lo, hi = bucket_range(i)
        rows[i] = (lo, hi, stats.histogram[i])
    return rows


def lateness_quantile(stats: ExecutorStats, q: float) -> int:
    """The ``q`` quantile of tick lateness (ns, a bucket's upper bound), from the histogram."""
    if not 0.0 <= q <= 1.0:
        raise ValueError("q must be in [0, 1]")
    counts = np.frombuffer(stats.histogram, dtype=np.uint64)
    total = int(counts.sum())
    if total == 0:
        return 0
    rank = max(1, int(np.ceil(q * total)))
    i = int(np.searchsorted(np.cumsum(counts), rank))
    return min(bucket_range(i)[1], stats.lateness_max_ns)
