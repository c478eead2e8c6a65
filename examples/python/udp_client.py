"""A MATLAB-style client of `conductor udp-gateway`, after the thesis' Fig. 3.5.

initState(port), readState(s) and cmdState(s, v) are the thesis' MATLAB functions: each
readState sends `GET` to the state's UDP port and parses the reply, each cmdState sends
`SET <v>`. Ports follow `conductor list` order from the gateway's base port; for sim-motor:
position = base, velocity = base + 1, command = base + 2 (checked with `INFO`).

The control law is the same PD as controller.py, written as a state-feedback row vector
(u = K·(r − x), x = [θ; ω]) the way the MATLAB original would.

Usage:
    python udp_client.py [--host 127.0.0.1] [--base-port 2827] [--target 1.0] [--seconds 3]
"""
import argparse
import json
import socket
import time


class State:
    """One state's UDP port."""

    def __init__(self, host, port, timeout):
        self.addr = (host, port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(timeout)

    def ask(self, text):
        self.sock.sendto(text.encode(), self.addr)
        reply = self.sock.recv(512).decode()
        if reply.startswith("ERR"):
            raise RuntimeError(f"{self.addr[1]} {text!r}: {reply}")
        return reply


def initState(port, host="127.0.0.1", timeout=1.0):  # noqa: N802 (the thesis' names)
    return State(host, port, timeout)


def readState(s):  # noqa: N802
    return float(s.ask("GET"))


def cmdState(s, value):  # noqa: N802
    return s.ask(f"SET {value!r}")


def infoState(s):  # noqa: N802
    return s.ask("INFO").split()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--base-port", type=int, default=2827)
    ap.add_argument("--target", type=float, default=1.0)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--period", type=float, default=0.01, help="control period (s)")
    args = ap.parse_args()

    x1 = initState(args.base_port, args.host)
    x2 = initState(args.base_port + 1, args.host)
    u1 = initState(args.base_port + 2, args.host)
    names = [infoState(s)[0] for s in (x1, x2, u1)]
    assert names[0].endswith("/position") and names[1].endswith("/velocity"), names
    assert names[2].endswith("/command"), names

    K = [5.0, 0.5]  # gains on [θ error, −ω]
    r = [args.target, 0.0]
    steps = 0
    clamped = 0
    end = time.monotonic() + args.seconds
    next_t = time.monotonic()
    while time.monotonic() < end:
        x = [readState(x1), readState(x2)]
        u = sum(k * (ri - xi) for k, ri, xi in zip(K, r, x))
        if cmdState(u1, u).endswith("CLAMPED"):
            clamped += 1
        steps += 1
        next_t += args.period
        time.sleep(max(0.0, next_t - time.monotonic()))
    final = readState(x1)
    cmdState(u1, 0.0)
    print(json.dumps({"steps": steps, "position": final, "clamped": clamped, "names": names}), flush=True)


if __name__ == "__main__":
    main()
