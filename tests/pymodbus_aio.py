#!/usr/bin/python3
"""A third-party Modbus peer for the interop test: pymodbus (Debian's python3-pymodbus) as a
simulated analog I/O module with fringe's generic-aio register map. Holding registers 0 and 1
(the DAC outputs, s16) are mirrored into input registers 0 and 1 (the ADC inputs) with a
fixed offset of +OFFSET counts on the sin channel, so the test can see that the values went
through this peer. Prints "listening PORT" once it serves.

usage: pymodbus_aio.py PORT [OFFSET_COUNTS]
"""
import logging
import sys
import threading

from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext
from pymodbus.server import StartTcpServer

logging.basicConfig(level=logging.CRITICAL)
port = int(sys.argv[1])
offset = int(sys.argv[2]) if len(sys.argv) > 2 else 0
inputs = ModbusSequentialDataBlock(0, [0] * 16)


class Outputs(ModbusSequentialDataBlock):
    def setValues(self, address, values):
        super().setValues(address, values)
        s = self.getValues(0, 2)
        sin = (s[0] - 65536 if s[0] >= 32768 else s[0]) + offset
        inputs.setValues(0, [sin & 0xFFFF, s[1]])


store = ModbusSlaveContext(hr=Outputs(0, [0] * 16), ir=inputs, zero_mode=True)
context = ModbusServerContext(slaves=store, single=True)
threading.Timer(0.5, lambda: print(f"listening {port}", flush=True)).start()
StartTcpServer(context=context, address=("127.0.0.1", port))
