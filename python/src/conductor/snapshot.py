"""A subsystem's tick as one sample: ``conductor/<subsystem>/snapshot``."""

import ctypes
from typing import List, Optional, Union

import iceoryx2 as iox2

from .abi import StateSample
from .bus import Bus, connect, validate_name
from .errors import BusError, UnknownSubsystem


class SnapshotReader:
    """Reads ``conductor/<subsystem>/snapshot``: every tick, one slice of :class:`StateSample`,
    entry ``i`` being the state of index ``i`` as of that tick (a slower state keeps its last
    sample; one never published has ``t_sample_ns == 0``, a NaN value and ``STALE``). The
    executor sends it, and notifies the event of the same name, before the tick's per-state
    samples: a controller of the whole subsystem wakes once and reads every joint of one tick::

        snap = SnapshotReader("right_leg", domain="minihubo")
        while True:
            samples = snap.wait(0.1)
            if samples is None:
                continue
            ...samples[i].value for the state of index i...
    """

    def __init__(self, subsystem: str, domain: Union[None, str, Bus] = None):
        self.bus = connect(domain)
        self.subsystem = validate_name("subsystem", subsystem)
        name = iox2.ServiceName.new(f"conductor/{subsystem}/snapshot")
        try:
            self._service = (
                self.bus.node.service_builder(name)
                .publish_subscribe(iox2.Slice[StateSample])
                .open()
            )
            self._port = self._service.subscriber_builder().buffer_size(2).create()
            self._event = self.bus.node.service_builder(name).event().open()
            self._listener = self._event.listener_builder().create()
        except Exception as e:
            if "DoesNotExist" in repr(e):
                raise UnknownSubsystem(
                    subsystem, self.bus.domain, f"conductor/{subsystem}/snapshot"
                ) from e
            raise BusError(f"opening {subsystem!r}'s snapshot: {e!r}") from e

    def latest(self) -> Optional[List[StateSample]]:
        """The newest snapshot queued since the last call, copied out (older ones are
        dropped), or ``None``."""
        newest = None
        while True:
            try:
                sample = self._port.receive()
            except Exception as e:
                raise BusError(f"receiving {self.subsystem!r}'s snapshot: {e!r}") from e
            if sample is None:
                return newest
            entries = sample.payload()
            # iceoryx2 0.10's Python binding gives a received slice's length in bytes (its
            # ports see the payload as bytes), not in entries.
            size, n = ctypes.sizeof(StateSample), entries.len()
            if n % size:
                raise BusError(
                    f"{self.subsystem!r}'s snapshot: {n} bytes is not a whole number of samples"
                )
            newest = [StateSample.from_buffer_copy(entries[i]) for i in range(n // size)]
            del entries, sample

    def wait(self, timeout: float = 1.0) -> Optional[List[StateSample]]:
        """The newest snapshot, sleeping on the snapshot event until one arrives or ``timeout``
        s pass (``None`` then)."""
        try:
            self._listener.try_wait()
            snap = self.latest()
            if snap is not None:
                return snap
            self._listener.timed_wait(iox2.Duration.from_secs_f64(max(timeout, 0.0)))
        except BusError:
            raise
        except Exception as e:
            raise BusError(f"waiting for {self.subsystem!r}'s snapshot: {e!r}") from e
        return self.latest()
