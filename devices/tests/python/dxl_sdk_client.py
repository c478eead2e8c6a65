"""Drives a Dynamixel bus with ROBOTIS' official dynamixel-sdk: ping, read, write, sync write,
sync read, bulk read, indirect addressing and reboot, checking that the servos behave as the
e-Manual says (torque off at power-on, goals not followed until torque is enabled, EEPROM and
indirect addresses locked while torque is on). Prints one JSON object with everything it
observed; the Rust test checks the values."""
import json
import sys

from dynamixel_sdk import (
    COMM_SUCCESS, DXL_HIBYTE, DXL_HIWORD, DXL_LOBYTE, DXL_LOWORD, GroupBulkRead,
    GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler,
)

path, ids = sys.argv[1], [int(i) for i in sys.argv[2].split(",")]
port, ph = PortHandler(path), PacketHandler(2.0)
assert port.openPort(), "open"
assert port.setBaudRate(1000000), "baud"
out = {}


def ok(res, err, what):
    assert res == COMM_SUCCESS, f"{what}: {ph.getTxRxResult(res)}"
    assert err == 0, f"{what}: {ph.getRxPacketError(err)}"


model, res, err = ph.ping(port, ids[0])
ok(res, err, "ping")
out["ping_model"] = model
found, res = ph.broadcastPing(port)
assert res == COMM_SUCCESS, ph.getTxRxResult(res)
out["broadcast_ids"] = sorted(found.keys())
out["broadcast_models"] = sorted({v[0] for v in found.values()})

torque, res, err = ph.read1ByteTxRx(port, ids[0], 64)
ok(res, err, "read torque")
out["torque_at_power_on"] = torque

pos, res, err = ph.read4ByteTxRx(port, ids[0], 132)
ok(res, err, "read")
out["read_present"] = pos

# A goal written with torque off is kept, and the shaft stays where it is.
res, err = ph.write4ByteTxRx(port, ids[0], 116, 3000)
ok(res, err, "write")
goal, res, err = ph.read4ByteTxRx(port, ids[0], 116)
ok(res, err, "read back")
out["write_readback"] = goal
pos, res, err = ph.read4ByteTxRx(port, ids[0], 132)
ok(res, err, "read present, torque off")
out["present_after_goal_torque_off"] = pos

# Indirect Address 1-4 -> Present Position (132-135), set up with torque off as the SDK's
# indirect_address example does.
for k in range(4):
    res, err = ph.write2ByteTxRx(port, ids[0], 168 + 2 * k, 132 + k)
    ok(res, err, f"indirect address {k + 1}")

res, err = ph.write1ByteTxRx(port, ids[0], 64, 1)
ok(res, err, "torque on")
pos, res, err = ph.read4ByteTxRx(port, ids[0], 132)
ok(res, err, "read present, torque on")
out["present_after_torque_on"] = pos
data, res, err = ph.read4ByteTxRx(port, ids[0], 224)
ok(res, err, "read indirect data")
out["indirect_data"] = data

# With torque on, an Indirect Address or EEPROM write is refused with Access Error (7).
res, err = ph.write2ByteTxRx(port, ids[0], 168, 128)
assert res == COMM_SUCCESS, ph.getTxRxResult(res)
out["indirect_address_with_torque_error"] = err
res, err = ph.write1ByteTxRx(port, ids[0], 11, 4)
assert res == COMM_SUCCESS
out["eeprom_with_torque_error"] = err

st = GroupSyncWrite(port, ph, 64, 1)
for i in ids:
    assert st.addParam(i, [1])
res = st.txPacket()
assert res == COMM_SUCCESS, ph.getTxRxResult(res)

sw = GroupSyncWrite(port, ph, 116, 4)
goals = {i: 1000 + 100 * i for i in ids}
for i, v in goals.items():
    assert sw.addParam(i, [DXL_LOBYTE(DXL_LOWORD(v)), DXL_HIBYTE(DXL_LOWORD(v)),
                           DXL_LOBYTE(DXL_HIWORD(v)), DXL_HIBYTE(DXL_HIWORD(v))])
res = sw.txPacket()
assert res == COMM_SUCCESS, ph.getTxRxResult(res)
out["sync_write_goals"] = [goals[i] for i in ids]

sr = GroupSyncRead(port, ph, 132, 4)
for i in ids:
    assert sr.addParam(i)
res = sr.txRxPacket()
assert res == COMM_SUCCESS, ph.getTxRxResult(res)
out["sync_read_present"] = [sr.getData(i, 132, 4) if sr.isAvailable(i, 132, 4) else None for i in ids]

br = GroupBulkRead(port, ph)
assert br.addParam(ids[0], 132, 4)
assert br.addParam(ids[-1], 146, 1)
res = br.txRxPacket()
assert res == COMM_SUCCESS, ph.getTxRxResult(res)
out["bulk_read"] = [br.getData(ids[0], 132, 4), br.getData(ids[-1], 146, 1)]

# REBOOT: RAM back to power-on, torque off, Goal Position = Present Position.
res, err = ph.reboot(port, ids[0])
ok(res, err, "reboot")
torque, res, err = ph.read1ByteTxRx(port, ids[0], 64)
ok(res, err, "torque after reboot")
out["torque_after_reboot"] = torque
goal, res, err = ph.read4ByteTxRx(port, ids[0], 116)
ok(res, err, "goal after reboot")
pos, res, err = ph.read4ByteTxRx(port, ids[0], 132)
ok(res, err, "present after reboot")
out["goal_present_after_reboot"] = [goal, pos]
address, res, err = ph.read2ByteTxRx(port, ids[0], 168)
ok(res, err, "indirect address 1 after reboot")
out["indirect_address_after_reboot"] = address

port.closePort()
print(json.dumps(out))
