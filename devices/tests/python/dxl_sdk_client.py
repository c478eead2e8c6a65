"""Drives a Dynamixel bus with ROBOTIS' official dynamixel-sdk: ping, read, write, sync write,
sync read, bulk read. Prints one JSON object with everything it observed."""
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

pos, res, err = ph.read4ByteTxRx(port, ids[0], 132)
ok(res, err, "read")
out["read_present"] = pos

res, err = ph.write4ByteTxRx(port, ids[0], 116, 3000)
ok(res, err, "write")
goal, res, err = ph.read4ByteTxRx(port, ids[0], 116)
ok(res, err, "read back")
out["write_readback"] = goal

# An EEPROM write with torque on is refused with Access Error (7).
res, err = ph.write1ByteTxRx(port, ids[0], 11, 4)
assert res == COMM_SUCCESS
out["eeprom_with_torque_error"] = err

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

port.closePort()
print(json.dumps(out))
