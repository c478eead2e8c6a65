"""The Conductor bus ABI (version 2) as ``ctypes`` types: the payloads of every service.

Byte for byte the layouts of ``bus/ABI.md`` (and of ``bus/src/abi.rs``): iceoryx2 connects a
Python port to a Rust one only when the type name, size and alignment agree, so a mismatch fails
to connect instead of misreading bytes.

Times are ``CLOCK_MONOTONIC`` nanoseconds, the clock of :func:`time.monotonic_ns` on Linux.
"""

import ctypes
import enum
from typing import List, Tuple

#: Version of the payload layouts; part of every type name and of the ``conductor.abi`` attribute.
ABI_VERSION = 2
#: Setpoints one :class:`CommandFrame` carries.
MAX_SETPOINTS = 64
#: Buckets of the lateness histogram in :class:`ExecutorStats`.
HISTOGRAM_BUCKETS = 280


class Status(enum.IntFlag):
    """The bits of :attr:`StateSample.status`."""

    #: No fresh reply this cycle: the value is the last good one.
    STALE = 1 << 0
    #: The last setpoint for this state was clamped to its limits.
    CLAMPED = 1 << 1
    #: The last setpoint for this state was refused (NaN/inf, read-only, or its device refuses
    #: setpoints now: see ``DISABLED`` and ``TRIPPED``).
    REJECTED = 1 << 2
    #: The command watchdog fired: the device is in its safe action.
    WATCHDOG = 1 << 3
    #: The device reports a fault.
    DEVICE_FAULT = 1 << 4
    #: The sample comes from a replayed recording.
    REPLAYED = 1 << 5
    #: The executor runs on simulated hardware.
    SIMULATED = 1 << 6
    #: The device is not driving (torque off, idle, being brought up): setpoints are refused.
    DISABLED = 1 << 7
    #: A watchdog trip or a fault took the device to its safe state; setpoints are refused until
    #: its ``enable`` state is set to 1.
    TRIPPED = 1 << 8

    def __str__(self) -> str:
        """The flag names as ``conductor`` prints them (``stale,clamped``), ``-`` for none."""
        return ",".join(flag_names(int(self))) or "-"


STALE = Status.STALE
CLAMPED = Status.CLAMPED
REJECTED = Status.REJECTED
WATCHDOG = Status.WATCHDOG
DEVICE_FAULT = Status.DEVICE_FAULT
REPLAYED = Status.REPLAYED
SIMULATED = Status.SIMULATED
DISABLED = Status.DISABLED
TRIPPED = Status.TRIPPED

_FLAG_NAMES = [
    "stale",
    "clamped",
    "rejected",
    "watchdog",
    "device-fault",
    "replayed",
    "simulated",
    "disabled",
    "tripped",
]


def flag_names(status: int) -> List[str]:
    """The names of the flags set in ``status``, in bit order (as ``conductor`` prints them)."""
    return [n for bit, n in enumerate(_FLAG_NAMES) if status & (1 << bit)]


class StateSample(ctypes.Structure):
    """One sample of one state (48 bytes), on ``conductor/<subsystem>/<state>``."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("tick", ctypes.c_uint64),
        ("t_sample_ns", ctypes.c_uint64),
        ("t_publish_ns", ctypes.c_uint64),
        ("value", ctypes.c_double),
        ("status", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 payload type name."""
        return "conductor.StateSample.v2"

    def __repr__(self) -> str:
        return (
            f"StateSample(seq={self.seq}, tick={self.tick}, t_sample_ns={self.t_sample_ns}, "
            f"t_publish_ns={self.t_publish_ns}, value={self.value!r}, "
            f"status={Status(self.status)})"
        )


class Setpoint(ctypes.Structure):
    """One setpoint of a :class:`CommandFrame` (16 bytes)."""

    _fields_ = [
        ("index", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("value", ctypes.c_double),
    ]

    @staticmethod
    def type_name() -> str:
        """The type name (only frames travel on their own)."""
        return "conductor.Setpoint.v2"


class CommandFrame(ctypes.Structure):
    """Setpoints for one subsystem (1048 bytes), on ``conductor/<subsystem>/commands``.

    The executor applies every setpoint of a frame in the same tick.
    """

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("t_send_ns", ctypes.c_uint64),
        ("count", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("entries", Setpoint * MAX_SETPOINTS),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 payload type name."""
        return "conductor.CommandFrame.v2"

    def push(self, index: int, value: float) -> bool:
        """Appends a setpoint; ``False`` when the frame is full."""
        if self.count >= MAX_SETPOINTS:
            return False
        e = self.entries[self.count]
        e.index, e.flags, e.value = index, 0, value
        self.count += 1
        return True


class ExecutorStats(ctypes.Structure):
    """Executor health (2432 bytes), on ``conductor/<subsystem>/stats`` about 10 times a second."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("t_ns", ctypes.c_uint64),
        ("ticks", ctypes.c_uint64),
        ("misses", ctypes.c_uint64),
        ("base_rate_hz", ctypes.c_double),
        ("achieved_rate_hz", ctypes.c_double),
        ("lateness_p50_ns", ctypes.c_uint64),
        ("lateness_p99_ns", ctypes.c_uint64),
        ("lateness_p999_ns", ctypes.c_uint64),
        ("lateness_max_ns", ctypes.c_uint64),
        ("bus_errors", ctypes.c_uint64),
        ("frames_applied", ctypes.c_uint64),
        ("setpoints_rejected", ctypes.c_uint64),
        ("setpoints_clamped", ctypes.c_uint64),
        ("watchdog_trips", ctypes.c_uint64),
        ("stale_states", ctypes.c_uint32),
        ("states", ctypes.c_uint32),
        ("rt_active", ctypes.c_uint32),
        ("cpu", ctypes.c_int32),
        ("bus_outages", ctypes.c_uint64),
        ("device_faults", ctypes.c_uint64),
        ("late_replies", ctypes.c_uint64),
        ("setpoints_refused", ctypes.c_uint64),
        ("devices", ctypes.c_uint32),
        ("devices_enabled", ctypes.c_uint32),
        ("devices_tripped", ctypes.c_uint32),
        ("devices_faulted", ctypes.c_uint32),
        ("links_down", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
        ("histogram", ctypes.c_uint64 * HISTOGRAM_BUCKETS),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 payload type name."""
        return "conductor.ExecutorStats.v2"

    def __repr__(self) -> str:
        return (
            f"ExecutorStats(seq={self.seq}, ticks={self.ticks}, misses={self.misses}, "
            f"achieved_rate_hz={self.achieved_rate_hz:.1f}, "
            f"lateness_p99_ns={self.lateness_p99_ns}, states={self.states}, "
            f"devices={self.devices})"
        )


def bucket_range(i: int) -> Tuple[int, int]:
    """The lateness values (ns, inclusive) that histogram bucket ``i`` holds.

    ``v = i`` for ``i < 16``; otherwise ``m << shift <= v < (m + 1) << shift`` with
    ``shift = i // 8 - 1`` and ``m = i % 8 + 8``. The last bucket also holds everything larger.
    """
    if not 0 <= i < HISTOGRAM_BUCKETS:
        raise IndexError(f"histogram bucket {i} (0..{HISTOGRAM_BUCKETS - 1})")
    if i < 16:
        return i, i
    shift = i // 8 - 1
    m = i % 8 + 8
    low = m << shift
    if i == HISTOGRAM_BUCKETS - 1:
        return low, (1 << 64) - 1
    return low, ((m + 1) << shift) - 1


for _t, _size in [(StateSample, 48), (Setpoint, 16), (CommandFrame, 1048), (ExecutorStats, 2432)]:
    assert ctypes.sizeof(_t) == _size and ctypes.alignment(_t) == 8, _t
