#!/usr/bin/python3
"""fringe instrument-sim checked by an independent VISA client: pyvisa with the pyvisa-py
backend (Debian python3-pyvisa-py), used as a user's script would. Raw sockets only (VXI-11
would need rpcbind). Usage: pyvisa_scpi.py FRINGE"""
import re
import struct
import subprocess
import sys
import time

import pyvisa

fringe = sys.argv[1]
sim = subprocess.Popen([fringe, "instrument-sim", "--port", "0", "--exit-after", "100", "--generator", "keysight-33500b",
                        "--digitizer", "generic-scope", "--clock-ppm", "0", "--gain", "1"],
                       stdout=subprocess.PIPE, text=True)
try:
    ports = {}
    deadline = time.time() + 20
    while len(ports) < 2 and time.time() < deadline:
        line = sim.stdout.readline()
        m = re.match(r"instrument-sim (\w+) scpi\+tcp://127\.0\.0\.1:(\d+)", line)
        if m:
            ports[m.group(1)] = int(m.group(2))
    assert len(ports) == 2, ports

    rm = pyvisa.ResourceManager("@py")
    gen = rm.open_resource(f"TCPIP0::127.0.0.1::{ports['generator']}::SOCKET", read_termination="\n", write_termination="\n", timeout=5000)
    dig = rm.open_resource(f"TCPIP0::127.0.0.1::{ports['digitizer']}::SOCKET", read_termination="\n", write_termination="\n", timeout=5000)

    # Identification and the error queue.
    idn = gen.query("*IDN?")
    assert idn.startswith("Keysight Technologies,33522B,"), idn
    assert dig.query("*IDN?").startswith("FRINGE,SIM-DIGITIZER"), "digitizer idn"
    assert gen.query("SYST:ERR?") == '0,"No error"'
    gen.write("NO:SUCH:COMMAND 1")
    assert gen.query("SYST:ERR?") == '-113,"Undefined header"'
    assert gen.query("SYST:ERR?") == '0,"No error"'
    gen.write("SOUR1:FUNC:ARB:SRAT 1e12")  # out of range
    assert gen.query("SYST:ERR?").startswith("-222,"), "range error"
    gen.write("*CLS")
    assert gen.query("*OPC?") == "1"

    # An arb upload as a definite-length block (write_binary_values), read back by its attributes.
    n = 1000
    codes = [int(round(32767 * (k / (n - 1) * 2 - 1))) for k in range(n)]
    gen.write("FORM:BORD SWAP")  # pyvisa writes little-endian by default
    gen.write_binary_values("SOUR1:DATA:ARB:DAC PYRAMP,", codes, datatype="h", is_big_endian=False)
    assert gen.query("SYST:ERR?") == '0,"No error"', "upload"
    assert int(gen.query("DATA:ATTR:POIN? PYRAMP")) == n
    assert abs(float(gen.query("DATA:ATTR:AVER? PYRAMP"))) < 1e-4
    # Floats, big-endian (FORM:BORD NORM), through DATA:ARB.
    gen.write("FORM:BORD NORM")
    ramp = [k / 99 * 1.6 - 0.8 for k in range(100)]
    gen.write_binary_values("SOUR2:DATA:ARB PYFLOAT,", ramp, datatype="f", is_big_endian=True)
    assert gen.query("SYST:ERR?") == '0,"No error"', "float upload"
    assert int(gen.query("DATA:ATTR:POIN? PYFLOAT")) == 100

    # Play it (continuous: output on without burst) and record it on the digitizer.
    gen.write("SOUR1:FUNC:ARB PYRAMP")
    gen.write("SOUR1:FUNC:ARB:SRAT 100000")
    gen.write("SOUR1:VOLT 1.0")
    gen.write("SOUR1:VOLT:OFFS 0")
    dig.write(":ACQ:SRAT 100000")
    dig.write(":ACQ:POIN 2000")
    dig.write(":TRIG:SOUR EXT")
    dig.write(":TRIG:POS 0")
    dig.write(":SING")
    assert dig.query(":TRIG:STAT?") == "WAIT"
    gen.write("OUTP1 ON")  # the generator's sync triggers the digitizer
    for _ in range(200):
        if dig.query(":TRIG:STAT?") == "STOP":
            break
        time.sleep(0.01)
    assert dig.query(":TRIG:STAT?") == "STOP"
    dig.write(":WAV:SOUR CHAN1")
    dig.write(":WAV:FORM WORD")
    dig.write(":WAV:BYT LSBF")
    pre = [float(x) for x in dig.query(":WAV:PRE?").split(",")]
    assert len(pre) == 10 and pre[2] == 2000, pre
    yinc, yorig, yref = pre[7], pre[8], pre[9]
    data = dig.query_binary_values(":WAV:DATA?", datatype="H", is_big_endian=False, container=list)
    assert len(data) == 2000, len(data)
    volts = [(c - yorig - yref) * yinc for c in data]
    # The ramp (-0.5..0.5 V over 1000 samples at 100 kS/s) comes back sample for sample.
    for k in range(50, 950, 50):
        want = codes[k] / 32767 * 0.5
        assert abs(volts[k] - want) < 2e-3, (k, volts[k], want)
    assert dig.query("SYST:ERR?") == '0,"No error"'
    # The same block as BYTE: half the bytes.
    dig.write(":WAV:FORM BYTE")
    assert len(dig.query_binary_values(":WAV:DATA?", datatype="B", container=list)) == 2000
    gen.close()
    dig.close()
    rm.close()
    print("pyvisa_scpi: ok (pyvisa", pyvisa.__version__ + ")")
finally:
    sim.terminate()
    sim.wait(timeout=10)
