"""Conductor bus ABI v2 for Python (ctypes + the official iceoryx2 package)."""
import ctypes

ABI_VERSION = 2
MAX_SETPOINTS = 64

# StateSample.status bits
STALE, CLAMPED, REJECTED, WATCHDOG, DEVICE_FAULT, REPLAYED, SIMULATED, DISABLED, TRIPPED = (
    1 << b for b in range(9)
)


class StateSample(ctypes.Structure):
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
        return "conductor.StateSample.v2"


class Setpoint(ctypes.Structure):
    _fields_ = [
        ("index", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("value", ctypes.c_double),
    ]


class CommandFrame(ctypes.Structure):
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("t_send_ns", ctypes.c_uint64),
        ("count", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("entries", Setpoint * MAX_SETPOINTS),
    ]

    @staticmethod
    def type_name() -> str:
        return "conductor.CommandFrame.v2"


assert ctypes.sizeof(StateSample) == 48 and ctypes.sizeof(CommandFrame) == 1048


def domain_config(domain: str):
    """The iceoryx2 config of a Conductor domain."""
    import iceoryx2 as iox2

    cfg = iox2.config.default()
    cfg.global_cfg.prefix = iox2.FileName.new(f"cdr_{domain}_")
    cfg.global_cfg.root_path = iox2.Path.new(f"/tmp/conductor/{domain}/")
    return cfg


def attributes(service) -> dict:
    """A service's attributes as {key: value} (first value of each key)."""
    out = {}
    for a in service.attributes.values:
        out.setdefault(a.key.to_string(), a.value.to_string())
    return out
