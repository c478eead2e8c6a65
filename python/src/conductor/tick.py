"""Sleeping until a subsystem's next tick, without polling."""

from typing import Union

import iceoryx2 as iox2

from .bus import Bus, connect, validate_name
from .errors import BusError, UnknownSubsystem
from .discovery import subsystems

#: The event id the executors notify (iceoryx2's default notifier id).
TICK_EVENT_ID = 0


class TickWaiter:
    """Listens to ``conductor/<subsystem>/tick``, which the executor notifies once per tick
    that published samples, after it published them.

    Notifications that arrive while nobody waits are counted, not lost: :meth:`wait` returns
    how many ticks passed since the last call (iceoryx2 reports them as one activation of event
    id 0 with a count). A controller loop reads its states after each wake-up::

        ticks = TickWaiter("right_leg", domain="minihubo")
        while True:
            ticks.wait(0.1)
            ...read states, send setpoints...
    """

    def __init__(self, subsystem: str, domain: Union[None, str, Bus] = None):
        self.bus = connect(domain)
        self.subsystem = validate_name("subsystem", subsystem)
        if subsystem not in subsystems(self.bus):
            raise UnknownSubsystem(subsystem, self.bus.domain, f"conductor/{subsystem}/tick")
        try:
            self._service = (
                self.bus.node.service_builder(iox2.ServiceName.new(f"conductor/{subsystem}/tick"))
                .event()
                .open()
            )
            self._listener = self._service.listener_builder().create()
        except Exception as e:
            raise BusError(f"listening to {subsystem!r}'s tick: {e!r}") from e

    @staticmethod
    def _count(activations) -> int:
        return sum(max(a.count, 1) for a in activations if a.id.as_value == TICK_EVENT_ID)

    def wait(self, timeout: float = 1.0) -> int:
        """Blocks until a tick comes or ``timeout`` s pass; returns the ticks signalled since
        the last call (0 on timeout)."""
        try:
            acts = self._listener.timed_wait(iox2.Duration.from_secs_f64(max(timeout, 0.0)))
        except Exception as e:
            raise BusError(f"waiting for {self.subsystem!r}'s tick: {e!r}") from e
        return self._count(acts)

    def try_consume(self) -> int:
        """Consumes pending notifications without blocking; returns how many ticks they count."""
        try:
            return self._count(self._listener.try_wait())
        except Exception as e:
            raise BusError(f"polling {self.subsystem!r}'s tick: {e!r}") from e
