"""The package's ctypes types against bus/ABI.md: every offset, size, flag bit and the doc's own
ctypes mirror (no executor needed; the live tests check the same bytes against Rust)."""

import ctypes
import re

import conductor
from conductor import abi

from conftest import WORKSPACE

DOC = (WORKSPACE / "bus" / "ABI.md").read_text()


def doc_table(title: str):
    """Rows (offset, field) of the layout table under the heading that starts with ``title``."""
    section = DOC.split(f"### `{title}`", 1)[1].split("\n#", 1)[0]
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not cells[0].isdigit():
            continue
        field = next(c for c in cells if c.startswith("`"))
        rows.append((int(cells[0]), field.split("`")[1]))
    return section, rows


def test_every_documented_offset_is_the_packages():
    for t in [abi.StateSample, abi.Setpoint, abi.CommandFrame, abi.ExecutorStats]:
        section, rows = doc_table(t.__name__)
        size = int(re.search(r"— (\d+) bytes", DOC.split(f"### `{t.__name__}`", 1)[1]).group(1))
        assert ctypes.sizeof(t) == size, t.__name__
        assert ctypes.alignment(t) == 8
        documented = {name: off for off, name in rows}
        fields = [f[0] for f in t._fields_]
        assert sorted(documented) == sorted(fields), t.__name__
        for name, off in documented.items():
            assert getattr(t, name).offset == off, f"{t.__name__}.{name}"


def test_type_names_carry_the_abi_version():
    for t in [abi.StateSample, abi.CommandFrame, abi.ExecutorStats]:
        assert t.type_name() == f"conductor.{t.__name__}.v{abi.ABI_VERSION}"
        assert f"`{t.type_name()}`" in DOC


def test_status_bits_are_the_documented_ones():
    text = DOC.split("`status` bits:", 1)[1].split("\n\n", 1)[0]
    bits = {name: int(bit) for bit, name in re.findall(r"(\d+) `([A-Z_]+)`", text)}
    assert bits == {f.name: f.value.bit_length() - 1 for f in abi.Status}
    assert abi.flag_names(abi.STALE | abi.WATCHDOG) == ["stale", "watchdog"]
    assert str(abi.STALE | abi.WATCHDOG) == "stale,watchdog" and str(abi.Status(0)) == "-"


def test_the_docs_ctypes_mirror_is_the_packages():
    block = DOC.split("<!-- conductor_abi.py -->", 1)[1].split("```python\n", 1)[1]
    ns: dict = {}
    exec(block.split("\n```", 1)[0], ns)
    for name in ["StateSample", "Setpoint", "CommandFrame", "ExecutorStats"]:
        mine, theirs = getattr(abi, name), ns[name]
        assert [(f, getattr(mine, f).offset) for f, _ in mine._fields_] == [
            (f, getattr(theirs, f).offset) for f, _ in theirs._fields_
        ], name
        assert ctypes.sizeof(mine) == ctypes.sizeof(theirs)
    assert ns["ABI_VERSION"] == abi.ABI_VERSION


def test_histogram_buckets_follow_the_documented_rule():
    # Contiguous, non-overlapping, v = i below 16, the last one open-ended.
    assert [abi.bucket_range(i) for i in range(16)] == [(i, i) for i in range(16)]
    for i in range(16, abi.HISTOGRAM_BUCKETS - 1):
        assert abi.bucket_range(i + 1)[0] == abi.bucket_range(i)[1] + 1
    assert abi.bucket_range(abi.HISTOGRAM_BUCKETS - 1)[1] == 2**64 - 1
    s = abi.ExecutorStats()
    for v in [3, 3, 20, 1000]:
        i = next(i for i in range(abi.HISTOGRAM_BUCKETS) if abi.bucket_range(i)[1] >= v)
        s.histogram[i] += 1
    s.lateness_max_ns = 1000
    assert conductor.lateness_quantile(s, 0.5) == 3
    assert conductor.lateness_quantile(s, 1.0) == 1000


def test_frames_hold_64_setpoints():
    f = abi.CommandFrame()
    assert all(f.push(i, float(i)) for i in range(abi.MAX_SETPOINTS))
    assert not f.push(99, 0.0)
    assert f.count == 64 and f.entries[63].index == 63


def test_bad_names_are_typed_errors():
    import pytest

    for bad in ["", "a b", "x" * 49, "a/b"]:
        with pytest.raises(conductor.InvalidName):
            conductor.states(bad)
    with pytest.raises(conductor.InvalidName):
        conductor.resolve("leg/stats", "nowhere")


def test_the_package_is_installed_with_its_dependencies():
    from importlib import metadata

    dist = metadata.distribution("conductor-py")
    assert dist.version == conductor.__version__
    reqs = " ".join(dist.requires or [])
    assert "iceoryx2" in reqs and "numpy" in reqs
