"""Discovery: the states of a domain and their metadata, read from iceoryx2's service records.

There is no registry process: every executor creates one iceoryx2 publish-subscribe service per
state, named ``conductor/<subsystem>/<state>``, whose attributes carry the metadata
(``bus/ABI.md``, *Discovery*). Listing the domain's services and keeping those with
``conductor.kind = state`` and ``conductor.abi = 2`` gives every state.
"""

import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple, Union

import iceoryx2 as iox2

from .abi import ABI_VERSION
from .bus import Bus, connect, validate_name
from .errors import AmbiguousState, BusError, UnknownState, UnknownSubsystem, WrongService

KEY_ABI = "conductor.abi"
KEY_KIND = "conductor.kind"
KEY_INDEX = "conductor.index"
KEY_UNITS = "conductor.units"
KEY_WRITABLE = "conductor.writable"
KEY_RATE = "conductor.rate_hz"
KEY_LIMITS = "conductor.limits"
KEY_DEVICE = "conductor.device"
KEY_WATCHDOG = "conductor.watchdog_ms"


@dataclass(frozen=True)
class StateInfo:
    """A state as discovery sees it: its name and the metadata of its service attributes."""

    #: Owning subsystem.
    subsystem: str
    #: State name within the subsystem.
    name: str
    #: Index within the subsystem: the address a setpoint uses.
    index: int
    #: Unit string (``rad``, ``N``, ...); empty when unitless.
    units: str
    #: Whether the state takes setpoints.
    writable: bool
    #: Publish rate (Hz).
    rate_hz: float
    #: Lower limit of setpoints (``-inf`` when unbounded); setpoints below are clamped.
    min: float
    #: Upper limit of setpoints (``inf`` when unbounded).
    max: float
    #: Owning device; empty when none.
    device: str
    #: Names of the live processes (iceoryx2 nodes) attached; the owner is ``executor/<subsystem>``.
    nodes: Tuple[str, ...] = field(default=(), compare=False)

    @property
    def qualified_name(self) -> str:
        """``subsystem/state``."""
        return f"{self.subsystem}/{self.name}"

    @property
    def service_name(self) -> str:
        """The iceoryx2 service name."""
        return f"conductor/{self.subsystem}/{self.name}"

    def clamp(self, value: float) -> float:
        """``value`` clamped to the limits, as the executor would."""
        return min(max(value, self.min), self.max)


def attributes(details) -> Dict[str, str]:
    """A service's attributes as ``{key: value}`` (first value of each key). Takes an iceoryx2
    ``ServiceDetails`` or port factory."""
    attrs = details.attributes
    attrs = attrs() if callable(attrs) else attrs
    out: Dict[str, str] = {}
    for a in attrs.values:
        out.setdefault(a.key.to_string(), a.value.to_string())
    return out


def _limit(s: str) -> float:
    return float(s.strip())  # "inf" and "-inf" included


def _info(name: str, attrs: Dict[str, str], nodes: Tuple[str, ...]) -> Optional[StateInfo]:
    parts = name.split("/")
    if len(parts) != 3 or parts[0] != "conductor":
        return None
    try:
        lo, hi = attrs[KEY_LIMITS].split(",")
        return StateInfo(
            subsystem=parts[1],
            name=parts[2],
            index=int(attrs[KEY_INDEX]),
            units=attrs.get(KEY_UNITS, ""),
            writable=attrs[KEY_WRITABLE] == "true",
            rate_hz=float(attrs[KEY_RATE]),
            min=_limit(lo),
            max=_limit(hi),
            device=attrs.get(KEY_DEVICE, ""),
            nodes=nodes,
        )
    except (KeyError, ValueError):
        return None


def _node_names(details) -> Tuple[str, ...]:
    names = []
    for n in details.nodes():
        if type(n).__name__ != "Alive":  # NodeState.Alive(AliveNodeView); dead ones are left out
            continue
        d = getattr(getattr(n, "_0", None), "details", None)
        if d is not None:
            names.append(d.name.as_str())
    return tuple(names)


def _services(bus: Bus) -> list:
    try:
        return iox2.Service.list(bus.config, iox2.ServiceType.Ipc)
    except Exception as e:
        raise BusError(f"listing the services of domain {bus.domain!r}: {e!r}") from e


def states(domain: Union[None, str, Bus] = None, pattern: Optional[str] = None) -> List[StateInfo]:
    """Every state of ``domain`` speaking this ABI, sorted by subsystem and index.

    ``pattern`` keeps the states whose ``subsystem/state`` matches it (a regular expression,
    searched). ``domain`` is a domain name (default ``$CONDUCTOR_DOMAIN``, else ``default``) or
    a :class:`~conductor.Bus`.
    """
    bus = connect(domain)
    rx = re.compile(pattern) if pattern else None
    out = []
    for d in _services(bus):
        if d.messaging_pattern() != iox2.MessagingPattern.PublishSubscribe:
            continue
        attrs = attributes(d)
        if attrs.get(KEY_KIND) != "state" or attrs.get(KEY_ABI) != str(ABI_VERSION):
            continue
        info = _info(d.name().to_string(), attrs, _node_names(d))
        if info is not None and (rx is None or rx.search(info.qualified_name)):
            out.append(info)
    out.sort(key=lambda s: (s.subsystem, s.index))
    return out


def subsystems(domain: Union[None, str, Bus] = None) -> List[str]:
    """The subsystems of ``domain`` that publish at least one state, sorted."""
    return sorted({s.subsystem for s in states(domain)})


def resolve(name: str, domain: Union[None, str, Bus] = None) -> StateInfo:
    """The state ``subsystem/state``, or a bare ``state`` name unique in the domain.

    Raises :class:`~conductor.UnknownState` (naming some that exist) or
    :class:`~conductor.AmbiguousState`.
    """
    bus = connect(domain)
    sub, _, st = name.rpartition("/")
    if sub:
        validate_name("subsystem", sub)
    validate_name("state", st)
    found = states(bus)
    hits = [s for s in found if s.name == st and (not sub or s.subsystem == sub)]
    if len(hits) == 1:
        return hits[0]
    if not hits:
        raise UnknownState(name, bus.domain, [s.qualified_name for s in found])
    raise AmbiguousState(name, bus.domain, [s.qualified_name for s in hits])


def _service_attributes(bus: Bus, service: str, kind: str) -> Dict[str, str]:
    for d in _services(bus):
        if d.name().to_string() == service:
            attrs = attributes(d)
            if attrs.get(KEY_ABI) != str(ABI_VERSION) or attrs.get(KEY_KIND) != kind:
                raise WrongService(
                    f"{service!r} is not a Conductor {kind} service of ABI {ABI_VERSION} "
                    f"(attributes {attrs})"
                )
            return attrs
    raise UnknownSubsystem(service.split("/")[1], bus.domain, service)


def watchdog(subsystem: str, domain: Union[None, str, Bus] = None) -> Optional[float]:
    """The command watchdog period (s) that ``subsystem``'s executor announces on its
    ``commands`` service (attribute ``conductor.watchdog_ms``), or ``None`` when it runs none.

    With a watchdog, a controller must send a command frame at least this often once it has
    sent one, or every writable device goes to its safe action (``bus/ABI.md``, *Watchdog*).
    Raises :class:`~conductor.WrongService` when the owner does not say (an older executor).
    """
    bus = connect(domain)
    validate_name("subsystem", subsystem)
    service = f"conductor/{subsystem}/commands"
    attrs = _service_attributes(bus, service, "commands")
    v = attrs.get(KEY_WATCHDOG)
    if v is None:
        raise WrongService(f"{service!r} does not announce its watchdog ({KEY_WATCHDOG})")
    return None if v == "off" else float(v) / 1e3
