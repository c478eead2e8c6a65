"""A Conductor controller in Python, on the `conductor` package (python/, over the official
iceoryx2 package).

It holds the simulated motor (`sim-motor`) at a target angle with a PD law on position and
velocity, sleeping on the subsystem's tick between cycles:

    u = Kp·(target − θ) − Kd·ω          (volts, clamped to the state's limits)

Usage:
    python controller.py [--domain D] [--target 1.0] [--seconds 3] [--kp 5] [--kd 0.5]

The domain defaults to $CONDUCTOR_DOMAIN or "default". Prints one JSON line at the end.
"""
import argparse
import json
import time

import conductor


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--domain", default=conductor.default_domain())
    ap.add_argument("--subsystem", default="motor")
    ap.add_argument("--target", type=float, default=1.0)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--kp", type=float, default=5.0)
    ap.add_argument("--kd", type=float, default=0.5)
    args = ap.parse_args()

    sub = args.subsystem
    pos = conductor.State(f"{sub}/position", args.domain, history=16)
    vel = conductor.State(f"{sub}/velocity", args.domain, history=16)
    cmd = conductor.Commander(args.domain)
    command = cmd.info(f"{sub}/command")  # units, limits and index from discovery
    ticks = conductor.TickWaiter(sub, args.domain)

    frames = 0
    u = 0.0
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        # Sleep until the executor has published a tick (or 100 ms pass).
        ticks.wait(0.1)
        p, v = pos.value, vel.value
        if p is None or v is None:
            continue
        u = command.clamp(args.kp * (args.target - p) - args.kd * v)
        # One frame per cycle, no waiting for the verdict: the executor applies it next tick.
        cmd.publish({command.qualified_name: u})
        frames += 1

    # Once more, asking what the executor made of it.
    ack = cmd.set(command.qualified_name, u)
    print(json.dumps({
        "frames": frames,
        "position": pos.value,
        "velocity": vel.value,
        "last_command": u,
        "target": args.target,
        "verdict": ack.verdict.name,
        "watchdog_s": cmd.watchdog(sub),
    }), flush=True)


if __name__ == "__main__":
    main()
