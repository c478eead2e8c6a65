"""Typed exceptions: every failure of this package is a :class:`ConductorError`."""

from typing import Iterable


class ConductorError(Exception):
    """Base of every error this package raises."""


class InvalidName(ConductorError, ValueError):
    """A domain, subsystem or state name that the bus cannot carry."""


class UnknownState(ConductorError, LookupError):
    """No state of that name in the domain (``known`` lists some that exist)."""

    def __init__(self, name: str, domain: str, known: Iterable[str] = ()):
        self.name, self.domain, self.known = name, domain, list(known)
        hint = f"; known: {', '.join(self.known[:12])}" if self.known else "; no states at all"
        super().__init__(f"no state {name!r} in domain {domain!r}{hint} (is its executor running?)")


class AmbiguousState(ConductorError, LookupError):
    """A bare state name that several subsystems own: qualify it as ``subsystem/state``."""

    def __init__(self, name: str, domain: str, candidates: Iterable[str]):
        self.name, self.domain, self.candidates = name, domain, list(candidates)
        super().__init__(
            f"state {name!r} is ambiguous in domain {domain!r}: {', '.join(self.candidates)}"
        )


class UnknownSubsystem(ConductorError, LookupError):
    """No executor of that subsystem in the domain (its service is missing)."""

    def __init__(self, name: str, domain: str, service: str):
        self.name, self.domain, self.service = name, domain, service
        super().__init__(
            f"no subsystem {name!r} in domain {domain!r} (no service {service!r}: is its "
            "executor running?)"
        )


class WrongService(ConductorError):
    """A service of that name exists but is not the Conductor service expected (a foreign
    service, or another ABI version)."""


class ReadOnlyState(ConductorError, ValueError):
    """A setpoint for a state that is not writable."""

    def __init__(self, name: str):
        self.name = name
        super().__init__(f"state {name!r} is read-only")


class NotFinite(ConductorError, ValueError):
    """A setpoint that is NaN or infinite."""

    def __init__(self, name: str, value: float):
        self.name, self.value = name, value
        super().__init__(f"setpoint {value!r} for {name!r} is not finite")


class FrameFull(ConductorError):
    """More setpoints for one subsystem than a command frame carries."""


class NotDelivered(ConductorError):
    """A command frame reached no receiver: no executor listens on the subsystem's commands."""

    def __init__(self, subsystem: str, domain: str):
        self.subsystem, self.domain = subsystem, domain
        super().__init__(
            f"no executor of {subsystem!r} in domain {domain!r} received the command frame "
            "(not delivered)"
        )


class Timeout(ConductorError, TimeoutError):
    """Nothing came in the time allowed (a sample, a tick, stats, a verdict)."""


class VerdictTimeout(Timeout):
    """The executor's verdict on a setpoint did not come in the time allowed: it is unknown
    whether the executor applied it (``pending`` names the states without a verdict)."""

    def __init__(self, pending: Iterable[str], timeout: float):
        self.pending, self.timeout = list(pending), timeout
        super().__init__(
            f"no verdict within {timeout} s for {', '.join(self.pending)} (is the executor "
            "ticking?): not known whether it took the setpoint"
        )


class BusError(ConductorError):
    """iceoryx2 refused an operation (wraps its exception as ``__cause__``)."""
