"""A process's handle on a Conductor domain: an iceoryx2 node with the domain's configuration."""

import os
import re
import threading
from typing import Dict, Optional, Union

import iceoryx2 as iox2

from .errors import BusError, InvalidName

_DOMAIN = re.compile(r"^[A-Za-z0-9_-]{1,48}$")
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")
#: Names the bus reserves for a subsystem's own services.
RESERVED_STATE_NAMES = ("commands", "tick", "stats", "snapshot", "surface")


def receive_copy(port, kind, what: str):
    """The next queued sample of subscriber ``port`` copied out as a ``kind`` (a ctypes
    structure of the ABI), its shared-memory slot handed back at once; ``None`` when the queue
    is empty. iceoryx2's failures are raised as ``BusError`` naming ``what``."""
    try:
        sample = port.receive()
    except Exception as e:
        raise BusError(f"receiving {what}: {e!r}") from e
    if sample is None:
        return None
    value = kind.from_buffer_copy(sample.payload().contents)
    del sample
    return value


def default_domain() -> str:
    """``$CONDUCTOR_DOMAIN``, else ``default``."""
    return os.environ.get("CONDUCTOR_DOMAIN") or "default"


def validate_domain(domain: str) -> str:
    """Returns ``domain`` if it is a valid domain name (1-48 of ``[A-Za-z0-9_-]``)."""
    if not isinstance(domain, str) or not _DOMAIN.match(domain):
        raise InvalidName(f"domain {domain!r}: 1-48 characters of [A-Za-z0-9_-]")
    return domain


def validate_name(what: str, name: str) -> str:
    """Returns ``name`` if it is a valid subsystem or state name."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise InvalidName(f"{what} {name!r}: 1-64 of [A-Za-z0-9_.-], not starting with . or -")
    if what == "state" and name in RESERVED_STATE_NAMES:
        raise InvalidName(f"state {name!r}: the name is reserved")
    return name


def domain_config(domain: str) -> "iox2.config.Config":
    """The iceoryx2 configuration of a Conductor domain (``bus/ABI.md``, *Domains*)."""
    validate_domain(domain)
    cfg = iox2.config.default()
    cfg.global_cfg.prefix = iox2.FileName.new(f"cdr_{domain}_")
    cfg.global_cfg.root_path = iox2.Path.new(f"/tmp/conductor/{domain}/")
    return cfg


class Bus:
    """One iceoryx2 node in one domain, from which states, commanders and waiters are made.

    Most users never make one: every class takes ``domain=`` and shares one :class:`Bus` per
    domain and thread (:func:`connect`). iceoryx2 ports are not thread-safe: use a bus (and
    the objects made from it) from the thread that made it.
    """

    def __init__(self, domain: Optional[str] = None, name: str = "conductor-py"):
        self.domain = validate_domain(default_domain() if domain is None else domain)
        self.config = domain_config(self.domain)
        try:
            self.node = (
                iox2.NodeBuilder.new()
                .name(iox2.NodeName.new(name))
                .config(self.config)
                .create(iox2.ServiceType.Ipc)
            )
        except Exception as e:  # iceoryx2's exceptions have no common base
            raise BusError(f"joining domain {self.domain!r}: {e!r}") from e

    def __repr__(self) -> str:
        return f"Bus(domain={self.domain!r})"


_local = threading.local()


def connect(domain: Union[None, str, Bus] = None) -> Bus:
    """The shared :class:`Bus` of ``domain`` (default: :func:`default_domain`) for this thread;
    a :class:`Bus` is returned as is."""
    if isinstance(domain, Bus):
        return domain
    name = validate_domain(default_domain() if domain is None else domain)
    buses: Dict[str, Bus] = getattr(_local, "buses", None) or {}
    _local.buses = buses
    if name not in buses:
        buses[name] = Bus(name)
    return buses[name]
