#!/usr/bin/python3
"""A third-party Modbus peer for the LabJack profiles: pymodbus (Debian's python3-pymodbus)
emulating the registers of a LabJack T7 (or T4/T8) that fringe's labjack-* profiles use, with
DAC0 wired to AIN0 and DAC1 to AIN1 (the self-test loop).

What it follows from LabJack's documentation (ljm_constants.json and the "Protocol Details
[Direct Modbus TCP]" page): one register space that functions 3 and 4 both read; FLOAT32 and
UINT32 values take two registers, most significant word first; DAC#(0:1) FLOAT32 at 1000/1002
(RW, a read returns what the DAC actually outputs, clamped to its range); AIN#(0:249) FLOAT32 at
0/2 (R); AIN#_RANGE FLOAT32 at 40000+2n, AIN#_NEGATIVE_CH UINT16 at 41000+n,
AIN#_RESOLUTION_INDEX UINT16 at 41500+n; TEST UINT32 at 55100 = 0x00112233; PRODUCT_ID
FLOAT32 at 60000. A 32-bit value must be accessed whole (LabJack's error list names
MODBUS_NUM_REGS_MUST_BE_EVEN, 2315): function 6 on a FLOAT32 register, or a read or write that
splits one, gets an exception reply (code 2 here; which code a real device returns has not
been checked on hardware). Unknown addresses and writes to read-only values get exception 2;
values a device cannot take (an AIN range it does not have, a non-finite DAC value, a
resolution index above the model's) get exception 4 for the whole request.

AIN readings: the DAC's output (quantised to the DAC's bits, clamped to its range) plus
Gaussian noise, clipped to the input range and quantised to the ADC's bits over it.

Prints "listening PORT" once it serves, then one line per configuration write
("write AIN0_RANGE = 10") and per refused request ("refused fc=6 @1000+1", "refused value
AIN0_RANGE = 2.3e-41").

usage: pymodbus_labjack.py PORT [--model t7|t4|t8] [--noise-v V] [--seed N]
"""
import argparse
import logging
import math
import random
import struct
import sys
import threading

from pymodbus.datastore import ModbusServerContext
from pymodbus.datastore.context import ModbusSlaveContext
from pymodbus.server import StartTcpServer

logging.basicConfig(level=logging.CRITICAL)

MODELS = {
    # product id, DAC bits and range (V), ADC bits, default AIN range (+-V), valid AIN#_RANGE
    # values (ljm_constants.json), highest AIN#_RESOLUTION_INDEX (T7 without -Pro)
    "t7": dict(product=7.0, dac_bits=12, dac_lo=0.0, dac_hi=5.0, adc_bits=16, ain_range=10.0,
               ranges=(0.0, 10.0, 1.0, 0.1, 0.01), max_res=8),
    "t4": dict(product=4.0, dac_bits=10, dac_lo=0.0, dac_hi=5.0, adc_bits=12, ain_range=10.0,
               ranges=(0.0, 10.0), max_res=5),
    "t8": dict(product=8.0, dac_bits=16, dac_lo=-0.1, dac_hi=10.0, adc_bits=15, ain_range=11.0,
               ranges=(0.0, 11.0, 9.6, 4.8, 2.4, 1.2, 0.6, 0.3, 0.15, 0.075, 0.036, 0.018), max_res=16),
}

ap = argparse.ArgumentParser()
ap.add_argument("port", type=int)
ap.add_argument("--model", choices=sorted(MODELS), default="t7")
ap.add_argument("--noise-v", type=float, default=4e-5)
ap.add_argument("--seed", type=int, default=1)
args = ap.parse_args()
m = MODELS[args.model]
rng = random.Random(args.seed)
lock = threading.Lock()


def f32_words(v):
    hi, lo = struct.unpack(">HH", struct.pack(">f", v))
    return [hi, lo]


def words_f32(w):
    return struct.unpack(">f", struct.pack(">HH", w[0], w[1]))[0]


# name, words, type, writable; the state in `val` (floats/ints by name)
VALUES = {0: ("AIN0", 2, "f32", False), 2: ("AIN1", 2, "f32", False),
          1000: ("DAC0", 2, "f32", True), 1002: ("DAC1", 2, "f32", True),
          40000: ("AIN0_RANGE", 2, "f32", True), 40002: ("AIN1_RANGE", 2, "f32", True),
          41000: ("AIN0_NEGATIVE_CH", 1, "u16", True), 41001: ("AIN1_NEGATIVE_CH", 1, "u16", True),
          41500: ("AIN0_RESOLUTION_INDEX", 1, "u16", True), 41501: ("AIN1_RESOLUTION_INDEX", 1, "u16", True),
          55100: ("TEST", 2, "u32", False), 60000: ("PRODUCT_ID", 2, "f32", False)}
val = {"DAC0": 0.0, "DAC1": 0.0, "AIN0_RANGE": 0.0, "AIN1_RANGE": 0.0, "AIN0_NEGATIVE_CH": 199, "AIN1_NEGATIVE_CH": 199,
       "AIN0_RESOLUTION_INDEX": 0, "AIN1_RESOLUTION_INDEX": 0, "TEST": 0x00112233, "PRODUCT_ID": m["product"]}


def dac_out(v):
    """What the DAC outputs for a written value: clamped, on the DAC's grid."""
    v = min(max(v, m["dac_lo"]), m["dac_hi"])
    q = (m["dac_hi"] - m["dac_lo"]) / 2 ** m["dac_bits"]
    return m["dac_lo"] + round((v - m["dac_lo"]) / q) * q


def ain(ch):
    rng_v = val[f"AIN{ch}_RANGE"] or m["ain_range"]
    v = dac_out(val[f"DAC{ch}"]) + rng.gauss(0.0, args.noise_v)
    v = min(max(v, -rng_v), rng_v)
    q = 2 * rng_v / 2 ** m["adc_bits"]
    return round(v / q) * q


def span(address, count):
    """The values a request covers, or None if it splits one or leaves the map."""
    out, a = [], address
    while a < address + count:
        if a not in VALUES:
            return None
        n = VALUES[a][1]
        if a + n > address + count:
            return None
        out.append(a)
        a += n
    return out


class LabJackContext(ModbusSlaveContext):
    def validate(self, fc, address, count=1):
        vals = span(address, count)
        ok = vals is not None
        if ok and fc == 6:
            ok = VALUES[vals[0]][1] == 1 and VALUES[vals[0]][3]
        if ok and fc in (6, 16):
            ok = all(VALUES[a][3] for a in vals)
        if ok and fc not in (3, 4, 6, 16):
            ok = False
        if not ok:
            print(f"refused fc={fc} @{address}+{count}", flush=True)
        return ok

    def getValues(self, fc, address, count=1):
        out = []
        with lock:
            for a in span(address, count):
                name, n, typ, _ = VALUES[a]
                if name.startswith("AIN") and n == 2 and typ == "f32" and name[3:].isdigit():
                    out += f32_words(ain(int(name[3:])))
                elif name.startswith("DAC"):
                    out += f32_words(dac_out(val[name]))
                elif typ == "f32":
                    out += f32_words(val[name])
                elif typ == "u32":
                    out += [val[name] >> 16, val[name] & 0xFFFF]
                else:
                    out.append(val[name])
        return out

    def setValues(self, fc, address, values):
        with lock:
            new, i = {}, 0
            for a in span(address, len(values)):
                name, n, typ, _ = VALUES[a]
                w = values[i:i + n]
                i += n
                new[name] = words_f32(w) if typ == "f32" else w[0]
            # Values the device cannot take (AIN_RANGE_INVALID, 2370, and the like) refuse the
            # whole request: raising here makes pymodbus answer exception 4.
            for name, v in new.items():
                ok = (
                    (name.startswith("DAC") and math.isfinite(v))
                    or (name.endswith("_RANGE") and any(v == words_f32(f32_words(r)) for r in m["ranges"]))
                    or (name.endswith("_NEGATIVE_CH") and v == 199)
                    or (name.endswith("_RESOLUTION_INDEX") and 0 <= v <= m["max_res"]))
                if not ok:
                    print(f"refused value {name} = {v:g}", flush=True)
                    raise ValueError(f"{name}: invalid value {v}")
            for name, v in new.items():
                val[name] = v
                if not name.startswith("DAC"):
                    print(f"write {name} = {v:g}", flush=True)


context = ModbusServerContext(slaves=LabJackContext(zero_mode=True), single=True)
threading.Timer(0.5, lambda: print(f"listening {args.port}", flush=True)).start()
StartTcpServer(context=context, address=("127.0.0.1", args.port))
