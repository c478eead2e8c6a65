"""Opens an SLCAN adapter with python-can's `slcan` interface and drives MIT-mode motor 1 as
the firmware demands: a command before Enter is ignored, Enter starts with no torque, commands
then move it towards 1 rad, and after Exit commands are ignored again. Replies are decoded with
this script's own unpacking. Then it asks an ODrive axis for its encoder estimates with a
remote frame. Prints one JSON object; the Rust test checks the values."""
import json
import struct
import sys
import time

import can

path = sys.argv[1]
bus = can.Bus(interface="slcan", channel=path, bitrate=1000000, sleep_after_open=0)


def uint(x, lo, hi, bits):
    x = min(max(x, lo), hi)
    return int((x - lo) * ((1 << bits) - 1) / (hi - lo))


def to_float(n, lo, hi, bits):
    return n * (hi - lo) / ((1 << bits) - 1) + lo


def command(p, v, kp, kd, t):  # AK80-9 ranges
    pi, vi = uint(p, -12.5, 12.5, 16), uint(v, -50, 50, 12)
    kpi, kdi, ti = uint(kp, 0, 500, 12), uint(kd, 0, 5, 12), uint(t, -18, 18, 12)
    return bytes([pi >> 8, pi & 0xFF, vi >> 4, ((vi & 0xF) << 4) | (kpi >> 8), kpi & 0xFF,
                  kdi >> 4, ((kdi & 0xF) << 4) | (ti >> 8), ti & 0xFF])


def reply(msg):
    d = msg.data
    p = (d[1] << 8) | d[2]
    v = (d[3] << 4) | (d[4] >> 4)
    t = ((d[4] & 0xF) << 8) | d[5]
    return d[0], to_float(p, -12.5, 12.5, 16), to_float(v, -50, 50, 12), to_float(t, -18, 18, 12)


def exchange(arb, data=None, remote=False):
    msg = can.Message(arbitration_id=arb, is_extended_id=False, is_remote_frame=remote,
                      dlc=8, data=data)
    bus.send(msg)
    r = bus.recv(timeout=1.0)
    assert r is not None, f"no reply to {arb:#x}"
    return r


ENTER, EXIT = bytes([0xFF] * 7 + [0xFC]), bytes([0xFF] * 7 + [0xFD])
out = {}
# Before Enter: answered, but the command is ignored (the motor does not move).
before = []
for _ in range(2):
    motor, p, v, t = reply(exchange(1, command(1.0, 0.0, 20.0, 1.0, 0.0)))
    before.append(p)
    time.sleep(0.05)
out["before_enter"] = before
r = exchange(1, ENTER)  # enter motor mode
out["enter_reply_id"] = r.arbitration_id
out["enter_reply_dlc"] = r.dlc
time.sleep(0.05)
# Enter again only polls: motor mode starts with no torque, the motor has not moved.
out["after_enter"] = reply(exchange(1, ENTER))[1]
positions = []
for _ in range(300):
    r = exchange(1, command(1.0, 0.0, 20.0, 1.0, 0.0))
    motor, p, v, t = reply(r)
    assert motor == 1
    positions.append(p)
    time.sleep(0.002)
out["positions_first_last"] = [positions[0], positions[-1]]
r = exchange(1, EXIT)  # exit motor mode
# After Exit: commands are ignored again.
after = []
for _ in range(2):
    motor, p, v, t = reply(exchange(1, command(-1.0, 0.0, 20.0, 1.0, 0.0)))
    after.append(p)
    time.sleep(0.05)
out["after_exit"] = after
r = exchange((4 << 5) | 0x09, remote=True)  # ODrive node 4: Get_Encoder_Estimates
out["odrive_reply_id"] = r.arbitration_id
out["odrive_estimates"] = list(struct.unpack("<ff", bytes(r.data)))
bus.shutdown()
print(json.dumps(out))
