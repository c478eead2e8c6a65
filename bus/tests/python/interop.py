"""Interop peer: the official iceoryx2 Python package against a Rust Conductor process.

Usage: interop.py <abi-module-dir> <domain>
Uses only the ctypes mirror from bus/ABI.md (extracted into <abi-module-dir>/conductor_abi.py).
Prints one JSON object per line; the Rust test checks them.
"""
import json
import sys
import time

sys.path.insert(0, sys.argv[1])
import conductor_abi as abi  # noqa: E402
import iceoryx2 as iox2  # noqa: E402

domain = sys.argv[2]
node = iox2.NodeBuilder.new().config(abi.domain_config(domain)).create(iox2.ServiceType.Ipc)


def out(**kw):
    print(json.dumps(kw), flush=True)


# 1. Subscribe to a state the Rust side publishes; read 50 consecutive samples.
svc = (
    node.service_builder(iox2.ServiceName.new("conductor/py/counter"))
    .publish_subscribe(abi.StateSample)
    .open()
)
out(event="attributes", attrs=abi.attributes(svc))
sub = svc.subscriber_builder().buffer_size(64).create()
seqs, values, ticks = [], [], []
deadline = time.time() + 20
while len(seqs) < 50 and time.time() < deadline:
    sample = sub.receive()
    if sample is None:
        time.sleep(0.002)
        continue
    s = sample.payload().contents
    seqs.append(s.seq)
    values.append(s.value)
    ticks.append(s.tick)
out(event="samples", seqs=seqs, values=values, ticks=ticks)

# 2. Send one command frame of three setpoints.
cmd = (
    node.service_builder(iox2.ServiceName.new("conductor/py/commands"))
    .publish_subscribe(abi.CommandFrame)
    .open()
)
pub = cmd.publisher_builder().create()
frame = abi.CommandFrame()
frame.seq = 7
frame.t_send_ns = time.monotonic_ns()
for i, (index, value) in enumerate([(0, 1.25), (1, -2.5), (2, 3.75)]):
    frame.entries[i].index = index
    frame.entries[i].value = value
frame.count = 3
sample = pub.loan_uninit()
sample = sample.write_payload(frame)
sample.send()
out(event="sent")
# Keep the publisher alive until the Rust side has read the frame (it closes our stdin).
sys.stdin.read()
