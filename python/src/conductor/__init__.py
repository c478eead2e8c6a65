"""Conductor for Python: the bus of the Conductor executors, over the official iceoryx2 package.

* :func:`states` — discovery: every state of a domain with its metadata.
* :class:`State` — one state: latest value, flags, and a history ring (numpy).
* :class:`Commander` — setpoints in command frames; ``set``/``send`` return the executor's
  verdict (:class:`Verdict` ``OK``, ``CLAMPED``, ``REJECTED``).
* :class:`TickWaiter` — sleep until a subsystem's next tick.
* :class:`SnapshotReader` — every state of a subsystem's tick in one sample.
* :class:`Stats` — an executor's health (:class:`ExecutorStats`).
* :mod:`conductor.abi` — every payload of the bus as ``ctypes`` types (``bus/ABI.md``).

A domain is named by ``domain=`` (default ``$CONDUCTOR_DOMAIN``, else ``default``). Every error
is a :class:`ConductorError`.
"""

from . import abi
from .abi import (
    ABI_VERSION,
    MAX_SETPOINTS,
    CommandFrame,
    ExecutorStats,
    Setpoint,
    StateSample,
    Status,
    flag_names,
)
from .bus import Bus, connect, default_domain, domain_config
from .commander import Ack, Commander, Verdict
from .discovery import StateInfo, resolve, states, subsystems, watchdog
from .errors import (
    AmbiguousState,
    BusError,
    ConductorError,
    FrameFull,
    InvalidName,
    NotDelivered,
    NotFinite,
    ReadOnlyState,
    Timeout,
    UnknownState,
    UnknownSubsystem,
    VerdictTimeout,
    WrongService,
)
from .state import SAMPLE_DTYPE, State
from .stats import Stats, histogram, lateness_quantile
from .snapshot import SnapshotReader
from .tick import TICK_EVENT_ID, TickWaiter

__version__ = "0.1.0"

__all__ = [
    "ABI_VERSION",
    "MAX_SETPOINTS",
    "SAMPLE_DTYPE",
    "TICK_EVENT_ID",
    "Ack",
    "AmbiguousState",
    "Bus",
    "BusError",
    "CommandFrame",
    "Commander",
    "ConductorError",
    "ExecutorStats",
    "FrameFull",
    "InvalidName",
    "NotDelivered",
    "NotFinite",
    "ReadOnlyState",
    "Setpoint",
    "State",
    "StateInfo",
    "StateSample",
    "Stats",
    "Status",
    "TickWaiter",
    "SnapshotReader",
    "Timeout",
    "UnknownState",
    "UnknownSubsystem",
    "Verdict",
    "VerdictTimeout",
    "WrongService",
    "abi",
    "connect",
    "default_domain",
    "domain_config",
    "flag_names",
    "histogram",
    "lateness_quantile",
    "resolve",
    "states",
    "subsystems",
    "watchdog",
]
