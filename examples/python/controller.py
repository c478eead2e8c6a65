"""A Conductor controller in Python: the official iceoryx2 package plus the ctypes mirror of the
bus ABI (conductor_abi.py, a verbatim copy of the block in bus/ABI.md).

It holds the simulated motor (`sim-motor`) at a target angle with a PD law on position and
velocity, sleeping on the subsystem's tick event between cycles:

    u = Kp·(target − θ) − Kd·ω          (volts, clamped to the state's limits)

Usage:
    python controller.py [--domain D] [--target 1.0] [--seconds 3] [--kp 5] [--kd 0.5]

The domain defaults to $CONDUCTOR_DOMAIN or "default". Prints one JSON line at the end.
"""
import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import conductor_abi as abi  # noqa: E402
import iceoryx2 as iox2  # noqa: E402


def open_state(node, name):
    """Subscribes to conductor/<name>; returns (subscriber, attributes)."""
    svc = (
        node.service_builder(iox2.ServiceName.new(f"conductor/{name}"))
        .publish_subscribe(abi.StateSample)
        .open()
    )
    return svc, svc.subscriber_builder().buffer_size(16).create(), abi.attributes(svc)


def latest(sub, last):
    """The newest sample in the queue, or `last` when it is empty."""
    while True:
        sample = sub.receive()
        if sample is None:
            return last
        last = abi.StateSample.from_buffer_copy(sample.payload().contents)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--domain", default=os.environ.get("CONDUCTOR_DOMAIN") or "default")
    ap.add_argument("--subsystem", default="motor")
    ap.add_argument("--target", type=float, default=1.0)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--kp", type=float, default=5.0)
    ap.add_argument("--kd", type=float, default=0.5)
    args = ap.parse_args()

    node = iox2.NodeBuilder.new().config(abi.domain_config(args.domain)).create(iox2.ServiceType.Ipc)
    sub = args.subsystem
    # Keep the services alive (the first element) for as long as we use their ports.
    pos_svc, pos, _ = open_state(node, f"{sub}/position")
    vel_svc, vel, _ = open_state(node, f"{sub}/velocity")
    cmd_svc, _, cmd_attrs = open_state(node, f"{sub}/command")
    index = int(cmd_attrs["conductor.index"])
    lo, hi = (float(x) for x in cmd_attrs["conductor.limits"].split(","))

    commands = (
        node.service_builder(iox2.ServiceName.new(f"conductor/{sub}/commands"))
        .publish_subscribe(abi.CommandFrame)
        .open()
    )
    publisher = commands.publisher_builder().create()
    tick_svc = node.service_builder(iox2.ServiceName.new(f"conductor/{sub}/tick")).event().open()
    tick = tick_svc.listener_builder().create()

    p = v = None
    frames = 0
    u = 0.0
    seq = 0
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        # Sleep until the executor has published a tick (or 100 ms pass).
        tick.timed_wait(iox2.Duration.from_millis(100))
        p, v = latest(pos, p), latest(vel, v)
        if p is None or v is None:
            continue
        u = args.kp * (args.target - p.value) - args.kd * v.value
        u = min(max(u, lo), hi)
        # One frame per cycle: the executor applies every setpoint of a frame in one tick.
        seq += 1
        frame = abi.CommandFrame()
        frame.seq = seq
        frame.t_send_ns = time.monotonic_ns()
        frame.entries[0].index = index
        frame.entries[0].value = u
        frame.count = 1
        publisher.loan_uninit().write_payload(frame).send()
        frames += 1

    print(json.dumps({
        "frames": frames,
        "position": p.value if p else None,
        "velocity": v.value if v else None,
        "last_command": u,
        "target": args.target,
    }), flush=True)
    # The last frame lives in our shared memory: let the executor's next tick take it.
    time.sleep(0.1)
    del pos_svc, vel_svc, cmd_svc


if __name__ == "__main__":
    main()
