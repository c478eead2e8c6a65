"""Reads what each servo holds with ROBOTIS' dynamixel-sdk, as an independent witness of what
a host left on the bus: Torque Enable (64), Hardware Error Status (70), Goal Position (116) and
Present Position (132). Usage: dxl_sdk_state.py PORT ID,ID,... [BAUD]. Prints one line per
servo: ID TORQUE HARDWARE_ERROR GOAL PRESENT."""
import sys

from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

path, ids = sys.argv[1], [int(i) for i in sys.argv[2].split(",")]
baud = int(sys.argv[3]) if len(sys.argv) > 3 else 1000000
port, ph = PortHandler(path), PacketHandler(2.0)
assert port.openPort(), "open"
assert port.setBaudRate(baud), "baud"


def read(fn, dxl_id, addr, what, tries=3):
    # A reply the SDK's packet timeout missed (a simulator starved of CPU on a loaded machine)
    # is asked again, as a host on a real bus would; a wrong or refused reply is not.
    for _ in range(tries):
        value, res, err = fn(port, dxl_id, addr)
        if res == COMM_SUCCESS:
            break
    assert res == COMM_SUCCESS, f"{dxl_id} {what}: {ph.getTxRxResult(res)}"
    assert err == 0, f"{dxl_id} {what}: {ph.getRxPacketError(err)}"
    return value


def signed(v):
    return v - (1 << 32) if v & 0x80000000 else v


for i in ids:
    torque = read(ph.read1ByteTxRx, i, 64, "torque enable")
    hw = read(ph.read1ByteTxRx, i, 70, "hardware error status")
    goal = signed(read(ph.read4ByteTxRx, i, 116, "goal position"))
    present = signed(read(ph.read4ByteTxRx, i, 132, "present position"))
    print(i, torque, hw, goal, present)
port.closePort()
