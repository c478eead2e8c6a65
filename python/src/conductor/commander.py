"""Sending setpoints, and learning what the executor made of them."""

import enum
import math
import time
from dataclasses import dataclass
from typing import Dict, Mapping, Optional, Tuple, Union

import iceoryx2 as iox2

from .abi import MAX_SETPOINTS, CommandFrame, StateSample, Status
from .bus import Bus, connect
from .discovery import StateInfo, resolve, watchdog
from .errors import (
    BusError,
    FrameFull,
    NotDelivered,
    NotFinite,
    ReadOnlyState,
    UnknownSubsystem,
    VerdictTimeout,
)


class Verdict(enum.Enum):
    """What the executor did with a setpoint, read from the flags of the state's samples."""

    #: Applied as sent.
    OK = "ok"
    #: Applied, clamped to the state's limits (``CLAMPED`` flag).
    CLAMPED = "clamped"
    #: Refused (``REJECTED`` flag): not finite, read-only, unknown, or its device refuses
    #: setpoints now (``DISABLED``/``TRIPPED``); see :attr:`Ack.reason`.
    REJECTED = "rejected"


@dataclass(frozen=True)
class Ack:
    """The executor's answer to one setpoint."""

    #: ``subsystem/state``.
    state: str
    #: The value sent.
    requested: float
    #: What the executor did.
    verdict: Verdict
    #: The first sample that reflects the setpoint (its value is the state's value then, not
    #: necessarily the setpoint: a joint takes time to get there).
    sample: StateSample

    @property
    def flags(self) -> Status:
        """The sample's flags."""
        return Status(self.sample.status)

    @property
    def ok(self) -> bool:
        """Whether the setpoint was applied (as sent or clamped)."""
        return self.verdict is not Verdict.REJECTED

    @property
    def reason(self) -> str:
        """Why a setpoint was rejected (empty otherwise)."""
        if self.verdict is not Verdict.REJECTED:
            return ""
        f = self.flags
        if f & Status.TRIPPED:
            why = "a fault" if f & Status.DEVICE_FAULT else (
                "the command watchdog" if f & Status.WATCHDOG else "a watchdog trip or a fault"
            )
            return (
                f"its device is tripped ({why}) and refuses setpoints until its enable state "
                "is set to 1"
            )
        if f & Status.DISABLED:
            return "its device is disabled (not driving) and refuses setpoints"
        return "not finite, read-only, or a channel its device does not take now"

    def __repr__(self) -> str:
        extra = f", reason={self.reason!r}" if self.reason else ""
        return (
            f"Ack({self.state!r}, requested={self.requested!r}, verdict={self.verdict.name}, "
            f"flags={Status(self.sample.status)}{extra})"
        )


class _Target:
    """A state commands go to, with a subscriber that reads the verdict."""

    def __init__(self, bus: Bus, info: StateInfo):
        self.info = info
        try:
            self.service = (
                bus.node.service_builder(iox2.ServiceName.new(info.service_name))
                .publish_subscribe(StateSample)
                .open()
            )
            depth = min(64, self.service.static_config.subscriber_max_buffer_size)
            self.port = self.service.subscriber_builder().buffer_size(depth).create()
        except Exception as e:
            raise BusError(f"subscribing to {info.qualified_name!r}: {e!r}") from e

    def drain(self) -> None:
        while self.port.receive() is not None:
            pass


class _Outbox:
    def __init__(self, bus: Bus, subsystem: str):
        name = f"conductor/{subsystem}/commands"
        try:
            self.service = (
                bus.node.service_builder(iox2.ServiceName.new(name))
                .publish_subscribe(CommandFrame)
                .open()
            )
            self.port = self.service.publisher_builder().create()
        except Exception as e:
            if "DoesNotExist" in repr(e):
                raise UnknownSubsystem(subsystem, bus.domain, name) from e
            raise BusError(f"opening {name!r}: {e!r}") from e
        self.seq = 0


class Commander:
    """Sends setpoints as command frames and returns the executor's verdict on each.

    >>> cmd = Commander(domain="minihubo")
    >>> cmd.set("right_leg/RKP", 0.6)
    Ack('right_leg/RKP', requested=0.6, verdict=OK, flags=simulated)
    >>> cmd.send({"right_leg/RKP": 3.0, "right_leg/RHP": -0.3})["right_leg/RKP"].verdict
    <Verdict.CLAMPED: 'clamped'>

    All setpoints of one subsystem go out in one frame, which the executor applies in one tick.
    The verdict is read from the state's samples: its ``CLAMPED`` and ``REJECTED`` flags are
    those of the newest setpoint for that state, so the second sample published after the send
    (the first may come from a tick that began before it) tells what became of it. That takes
    one to two publish periods of the state; a control loop that does not need it uses
    :meth:`publish`, which only sends.

    Values are checked first as the executor would check them: a NaN/inf value raises
    :class:`~conductor.NotFinite`, a read-only state :class:`~conductor.ReadOnlyState`
    (``validate=False`` sends them anyway, to see the executor refuse them).
    """

    def __init__(self, domain: Union[None, str, Bus] = None):
        self.bus = connect(domain)
        self._infos: Dict[str, StateInfo] = {}
        self._targets: Dict[str, _Target] = {}
        self._outboxes: Dict[str, _Outbox] = {}

    def info(self, name: str) -> StateInfo:
        """The metadata of state ``name`` (resolved once, then cached)."""
        if name not in self._infos:
            self._infos[name] = resolve(name, self.bus)
        return self._infos[name]

    def watchdog(self, subsystem: str) -> Optional[float]:
        """The subsystem's command watchdog period (s), or ``None`` when it has none: with one,
        send a frame at least this often or its devices go to their safe action."""
        return watchdog(subsystem, self.bus)

    def _frames(
        self, setpoints: Mapping[str, float], validate: bool
    ) -> Dict[str, Tuple[CommandFrame, list]]:
        frames: Dict[str, Tuple[CommandFrame, list]] = {}
        for name, value in setpoints.items():
            info = self.info(name)
            value = float(value)
            if validate:
                if not math.isfinite(value):
                    raise NotFinite(info.qualified_name, value)
                if not info.writable:
                    raise ReadOnlyState(info.qualified_name)
            frame, names = frames.setdefault(info.subsystem, (CommandFrame(), []))
            if not frame.push(info.index, value):
                raise FrameFull(
                    f"more than {MAX_SETPOINTS} setpoints for subsystem {info.subsystem!r}"
                )
            names.append((info.qualified_name, value))
        return frames

    def _send_frames(self, frames: Dict[str, Tuple[CommandFrame, list]]) -> None:
        for subsystem, (frame, _) in frames.items():
            ob = self._outboxes.get(subsystem)
            if ob is None:
                ob = self._outboxes[subsystem] = _Outbox(self.bus, subsystem)
            ob.seq += 1
            frame.seq = ob.seq
            frame.t_send_ns = time.monotonic_ns()
            try:
                ob.port.update_connections()
                reached = ob.port.loan_uninit().write_payload(frame).send()
            except Exception as e:
                raise BusError(f"sending a command frame to {subsystem!r}: {e!r}") from e
            if reached == 0:
                raise NotDelivered(subsystem, self.bus.domain)

    def publish(self, setpoints: Mapping[str, float], validate: bool = True) -> None:
        """Sends ``{state: value}`` (one frame per subsystem) without waiting for a verdict.

        Raises :class:`~conductor.NotDelivered` when no executor receives a frame.
        """
        self._send_frames(self._frames(setpoints, validate))

    def send(
        self,
        setpoints: Mapping[str, float],
        timeout: Optional[float] = None,
        validate: bool = True,
    ) -> Dict[str, Ack]:
        """Sends ``{state: value}`` (one frame per subsystem) and returns each state's
        :class:`Ack` (keyed ``subsystem/state``) once the executor's samples tell its verdict.

        Raises :class:`~conductor.NotDelivered` when no executor receives a frame, and
        :class:`~conductor.VerdictTimeout` when a state publishes no telling sample within
        ``timeout`` s (default: 1 s plus three publish periods of the slowest state).
        """
        frames = self._frames(setpoints, validate)
        if timeout is None:
            slowest = min((self.info(n).rate_hz for n in setpoints), default=1.0)
            timeout = 1.0 + 3.0 / max(slowest, 1e-3)
        targets = {}
        for _, names in frames.values():
            for name, value in names:
                t = self._targets.get(name)
                if t is None:
                    t = self._targets[name] = _Target(self.bus, self.info(name))
                t.drain()  # what was queued before the send says nothing about it
                targets[name] = (t, value)
        t_send = time.monotonic_ns()
        self._send_frames(frames)
        after = {name: 0 for name in targets}
        acks: Dict[str, Ack] = {}
        deadline = time.monotonic() + timeout
        while len(acks) < len(targets):
            for name, (t, value) in targets.items():
                if name in acks:
                    continue
                while True:
                    sample = t.port.receive()
                    if sample is None:
                        break
                    s = StateSample.from_buffer_copy(sample.payload().contents)
                    del sample
                    if s.t_publish_ns <= t_send:
                        continue
                    after[name] += 1
                    if after[name] >= 2:
                        acks[name] = Ack(name, value, _verdict(s.status), s)
                        break
            if len(acks) < len(targets):
                if time.monotonic() >= deadline:
                    raise VerdictTimeout([n for n in targets if n not in acks], timeout)
                time.sleep(0.0005)
        return {name: acks[name] for name in targets}

    def set(
        self,
        state: str,
        value: float,
        timeout: Optional[float] = None,
        validate: bool = True,
    ) -> Ack:
        """Sends one setpoint and returns the executor's :class:`Ack` (see :meth:`send`)."""
        acks = self.send({state: value}, timeout=timeout, validate=validate)
        return acks[self.info(state).qualified_name]


def _verdict(status: int) -> Verdict:
    if status & Status.REJECTED:
        return Verdict.REJECTED
    if status & Status.CLAMPED:
        return Verdict.CLAMPED
    return Verdict.OK
