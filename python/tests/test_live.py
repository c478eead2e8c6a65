"""The package against a live executor: the simulated mini-Hubo right leg
(deploy/minihubo-right-leg.toml), run by the real conductor-executor in a domain of its own."""

import math
import subprocess
import sys
import time

import numpy as np
import pytest

import conductor
from conductor import Status, Verdict

from conftest import SUBSYSTEM, manifest_states

LEG = SUBSYSTEM


def test_discovery_lists_every_state_with_the_manifests_metadata(leg):
    found = conductor.states(leg.domain)
    declared = manifest_states()["states"]
    assert [s.name for s in found] == list(declared)  # bus index order = manifest order
    for i, s in enumerate(found):
        d = declared[s.name]
        assert (s.subsystem, s.index) == (LEG, i)
        assert s.units == d.get("units", "")
        assert s.writable == d.get("writable", False)
        assert s.min == d.get("min", -math.inf) and s.max == d.get("max", math.inf)
        assert s.rate_hz == d["rate_hz"]
        assert s.device == d["device"]
        assert f"executor/{LEG}" in s.nodes
    assert conductor.subsystems(leg.domain) == [LEG]
    assert [s.name for s in conductor.states(leg.domain, pattern=r"/R.P$")] == [
        "RAP",
        "RKP",
        "RHP",
    ]
    # A bare name resolves when it is unique; a wrong one says what exists.
    assert conductor.resolve("RKP", leg.domain).qualified_name == f"{LEG}/RKP"
    with pytest.raises(conductor.UnknownState) as e:
        conductor.resolve(f"{LEG}/knee", leg.domain)
    assert f"{LEG}/RKP" in e.value.known
    # Another domain sees nothing of it.
    assert conductor.states(f"{leg.domain}-other") == []


def test_state_keeps_value_flags_and_a_history_ring(leg):
    st = conductor.State(f"{LEG}/Fz", leg.domain, history=64)
    first = st.wait()
    assert st.flags & Status.SIMULATED and not st.flags & Status.STALE
    assert st.info.units == "N"
    deadline = time.monotonic() + 10
    while st.wait().seq < first.seq + 100:
        assert time.monotonic() < deadline
    h = st.history()
    assert len(h) == 64 == len(st)  # the ring is full and keeps the newest 64
    assert h["seq"][-1] == st.sample.seq and h["seq"][0] == st.sample.seq - 63
    assert np.all(np.diff(h["seq"].astype(np.int64)) == 1) and st.missed == 0
    # Fz publishes at 100 Hz of the 500 Hz base tick: every 5th tick, in order.
    assert np.all(h["tick"] % 5 == 0) and np.all(np.diff(h["tick"].astype(np.int64)) > 0)
    assert np.all(np.diff(h["t_sample_ns"].astype(np.int64)) > 0)
    assert np.all(h["t_publish_ns"] >= h["t_sample_ns"])
    assert np.all(h["status"] & int(Status.SIMULATED))
    # The simulated sensor: 20 N per unit of a sine around -2 units of offset.
    assert np.all(np.abs(st.values()) < 100)
    recent = st.history(seconds=0.1)
    h = st.history()
    assert np.array_equal(recent, h[h["t_sample_ns"] >= h["t_sample_ns"][-1] - 100_000_000])
    assert 5 <= len(recent) < len(h)


def test_set_returns_ok_clamped_and_rejected(leg):
    cmd = conductor.Commander(leg.domain)
    stats = conductor.Stats(LEG, leg.domain)
    before = stats.wait()
    rkp = conductor.State(f"{LEG}/RKP", leg.domain)

    ack = cmd.set(f"{LEG}/RKP", 0.6)
    assert ack.verdict is Verdict.OK and ack.ok, ack
    assert not ack.flags & (Status.CLAMPED | Status.REJECTED)

    # Above its limit (max 2.4): applied at the limit, flagged.
    ack = cmd.set("RKP", 3.0)
    assert ack.verdict is Verdict.CLAMPED and ack.ok, ack
    assert ack.state == f"{LEG}/RKP" and ack.requested == 3.0
    deadline = time.monotonic() + 10
    while abs(rkp.wait().value - 2.4) > 1e-3:
        cmd.publish({"RKP": 3.0})  # keep the watchdog fed while the joint moves
        assert time.monotonic() < deadline, rkp.value
    assert rkp.flags & Status.CLAMPED  # it stays set ...
    ack = cmd.set("RKP", 1.0)  # ... until the next setpoint of that state is within limits
    assert ack.verdict is Verdict.OK and not ack.flags & Status.CLAMPED, ack

    # Refused by the executor: checked here first, unless told to send it anyway.
    with pytest.raises(conductor.NotFinite):
        cmd.set("RKP", math.nan)
    with pytest.raises(conductor.ReadOnlyState):
        cmd.set("Fz", 1.0)
    ack = cmd.set("RKP", math.nan, validate=False)
    assert ack.verdict is Verdict.REJECTED and not ack.ok, ack
    assert "not finite" in ack.reason
    assert cmd.set("Fz", 1.0, validate=False).verdict is Verdict.REJECTED
    # A later good setpoint clears REJECTED.
    assert cmd.set("RKP", 0.5).verdict is Verdict.OK

    after = stats.wait(newer_than=stats.wait().seq)
    assert after.setpoints_rejected - before.setpoints_rejected == 2
    assert after.setpoints_clamped - before.setpoints_clamped >= 1


def test_send_bundles_a_subsystems_setpoints_in_one_frame(leg):
    cmd = conductor.Commander(leg.domain)
    stats = conductor.Stats(LEG, leg.domain)
    cmd.set("RHP", 0.0)  # connections made; the frames counted from here are ours
    before = stats.wait(newer_than=stats.wait().seq)
    acks = cmd.send({"RKP": 0.3, "RHP": -0.2, "RAR": 5.0})
    assert list(acks) == [f"{LEG}/RKP", f"{LEG}/RHP", f"{LEG}/RAR"]
    assert [a.verdict for a in acks.values()] == [Verdict.OK, Verdict.OK, Verdict.CLAMPED]
    after = stats.wait(newer_than=stats.wait().seq)
    assert after.frames_applied - before.frames_applied == 1


def test_tick_waiter_wakes_after_the_ticks_samples_and_counts_missed_ticks(leg):
    states = [conductor.State(s.qualified_name, leg.domain) for s in conductor.states(leg.domain)]
    ticks = conductor.TickWaiter(LEG, leg.domain)
    ticks.wait(1.0)
    for st in states:
        st.update()
    fresh = 0
    for _ in range(50):
        assert ticks.wait(1.0) >= 1
        # Notified after the tick's samples were published: a wake-up finds new ones (unless
        # the previous read already took them, when that tick's notification came after it).
        fresh += sum(st.update() for st in states) > 0
    assert fresh >= 45, fresh
    # Ticks that come while nobody waits are counted, not coalesced into one.
    ticks.try_consume()
    time.sleep(0.3)
    assert ticks.try_consume() >= 10
    with pytest.raises(conductor.UnknownSubsystem):
        conductor.TickWaiter("arm", leg.domain)


def test_the_snapshot_carries_every_state_of_one_tick(leg):
    infos = sorted(conductor.states(leg.domain), key=lambda s: s.index)
    snap = conductor.SnapshotReader(LEG, leg.domain)
    taken = [snap.wait(1.0) for _ in range(20)]
    assert all(t is not None and len(t) == len(infos) for t in taken), taken
    ticks = [max(e.tick for e in t) for t in taken]
    assert ticks == sorted(set(ticks)), f"each wake-up a newer tick: {ticks}"
    # The leg's states are all simulated: every entry that has been published says so.
    for t in taken:
        for e in t:
            assert e.t_sample_ns == 0 or e.status & Status.SIMULATED, e
    # Entry i is the sample that the state of index i has on its own service: subscribe to
    # every state, take snapshots, and find each entry in that state's history.
    states = [conductor.State(i.qualified_name, leg.domain, history=4096) for i in infos]
    snap.latest()
    later = [snap.wait(1.0) for _ in range(20)]
    time.sleep(0.05)
    for st in states:
        st.update()
    for t in later:
        for i, e in enumerate(t):
            if e.t_sample_ns == 0:
                continue
            h = states[i].history()
            seen = h[(h["t_sample_ns"] == e.t_sample_ns) & (h["seq"] == e.seq)]
            assert len(seen) == 1 and seen["value"][0] == e.value, (infos[i].name, e)
    with pytest.raises(conductor.UnknownSubsystem):
        conductor.SnapshotReader("arm", leg.domain)


def test_stats_carry_the_executors_health(leg):
    stats = conductor.Stats(LEG, leg.domain)
    a = stats.wait()
    b = stats.wait(newer_than=a.seq)
    assert b.seq > a.seq and b.ticks > a.ticks and b.t_ns > a.t_ns
    assert b.base_rate_hz == 500.0
    assert b.states == 9 and b.devices == 9
    assert b.devices_tripped == 0 and b.links_down == 0
    assert b.cpu >= -1 and b.rt_active in (0, 1)
    # The histogram and the percentiles the executor computed from it agree.
    assert sum(b.histogram) > 0
    assert conductor.lateness_quantile(b, 0.5) == b.lateness_p50_ns
    assert conductor.lateness_quantile(b, 0.99) == b.lateness_p99_ns
    assert b.lateness_p50_ns <= b.lateness_p99_ns <= b.lateness_max_ns
    h = conductor.histogram(b)
    assert int(h["count"].sum()) == sum(b.histogram)


def test_the_watchdog_period_is_on_the_bus_and_keeps_its_contract(own_leg):
    d = own_leg.domain
    cmd = conductor.Commander(d)
    assert cmd.watchdog(LEG) == 0.5  # watchdog_ms = 500 in the manifest
    assert conductor.watchdog(LEG, d) == 0.5
    rkp = conductor.State(f"{LEG}/RKP", d)
    rkp.wait()
    # Armed by the first frame; silent before it.
    assert not rkp.flags & Status.WATCHDOG
    t_send = time.monotonic_ns()
    assert cmd.set("RKP", 0.4).verdict is Verdict.OK
    deadline = time.monotonic() + 10
    while not rkp.wait().status & Status.WATCHDOG:
        assert time.monotonic() < deadline, "the watchdog did not fire"
    # Not before its period (the frame was taken at the tick after the send).
    assert rkp.sample.t_sample_ns - t_send >= 0.5e9 - 0.05e9
    stats = conductor.Stats(LEG, d)
    assert stats.wait(newer_than=stats.wait().seq).watchdog_trips == 1
    # Simulated servos have no lifecycle: the next frame clears WATCHDOG and is taken.
    ack = cmd.set("RKP", 0.4)
    assert ack.verdict is Verdict.OK and not ack.flags & Status.WATCHDOG, ack


def test_a_frame_nobody_receives_is_not_delivered(own_leg):
    d = own_leg.domain
    cmd = conductor.Commander(d)
    assert cmd.set("RKP", 0.2).ok
    assert own_leg.stop() == 0, own_leg.stderr()
    # The commands service outlives the executor while we hold it, with no receiver on it.
    with pytest.raises(conductor.NotDelivered):
        cmd.publish({"RKP": 0.3})
    with pytest.raises(conductor.NotDelivered):
        cmd.set("RKP", 0.3)


def test_the_readme_drives_the_leg_in_a_dozen_lines(own_leg):
    from conftest import WORKSPACE

    readme = (WORKSPACE / "python" / "README.md").read_text()
    code = readme.split("```python\n", 1)[1].split("\n```", 1)[0]
    assert len(code.splitlines()) <= 13
    assert 'DOMAIN = "minihubo"' in code
    code = code.replace('DOMAIN = "minihubo"', f'DOMAIN = "{own_leg.domain}"')
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    ack, last = out.stdout.strip().splitlines()
    assert "verdict=OK" in ack, ack
    value, *_, lo, hi = last.split()
    # The knee swung 0.6 ± 0.4 rad behind its 50 ms servo lag.
    assert 0.1 < float(lo) < 0.45 and 0.75 < float(hi) < 1.1, last
    assert 0.1 < float(value) < 1.1
    assert " simulated " in last
