#!/usr/bin/env bash
# fringe's SPI and SSI position words against a third-party peer (docs/dut-readouts.md): fringe's
# emitter writes the wire signals as CSV, Debian's sigrok-cli turns them into a sigrok session
# (.sr) and decodes it with libsigrokdecode's spi decoder; fringe decodes the same .sr (read
# back by its sigrok reader, in blocks that split frames). The words, their count and their
# timing must agree, and both must equal the emitted positions.
set -euo pipefail
TOOL="$1"
PY=/usr/bin/python3
command -v sigrok-cli >/dev/null || { echo "FAIL: sigrok-cli not installed (scripts/setup --test)" >&2; exit 1; }
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
H=2   # the tool's half clock period in samples

# SPI: every mode, both bit orders, word lengths from 1 to 64; frames with a dropped clock (no
# word from either decoder) and with a flipped bit (the same wrong word from both).
n=0
for mode in 0 1 2 3; do
  for order in msb lsb; do
    for bits in 1 7 16 33 64; do
      tag="spi-$mode-$order-$bits"
      "$TOOL" emit spi $mode $bits $order 40 $((mode * 100 + bits)) "$dir/$tag.csv" > "$dir/$tag.truth"
      sigrok-cli -I "csv:column_formats=l,l,l:header=yes:samplerate=1000000" -i "$dir/$tag.csv" -o "$dir/$tag.sr"
      "$TOOL" decode spi $mode $bits $order "$dir/$tag.sr" > "$dir/$tag.fringe"
      sigrok-cli -i "$dir/$tag.sr" --protocol-decoder-samplenum \
        -P "spi:clk=clk:miso=data:cs=cs:cpol=$((mode >> 1)):cpha=$((mode & 1)):wordsize=$bits:bitorder=$order-first" \
        -A spi=miso-data > "$dir/$tag.sigrok"
      $PY - "$dir/$tag" $bits $((mode & 1)) $H <<'PY' || fail "$tag"
import json, sys
base, bits, cpha, h = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
truth = [tuple(map(int, l.split())) for l in open(base + ".truth")]
lines = open(base + ".fringe").read().splitlines()
stats = json.loads(lines[-1].split(" ", 1)[1])
fr = [tuple(map(int, l.split())) for l in lines[:-1]]
sg = []
for l in open(base + ".sigrok"):   # "ss-es spi-1: HEX"
    span, _, hexv = l.split()
    sg.append((int(span.split("-")[0]), int(hexv, 16)))
assert len(fr) == len(truth), (len(fr), len(truth))
dropped = {i for i in range(len(truth)) if i % 12 == 5}
flipped = {i for i in range(len(truth)) if i % 12 == 3}
assert stats["short_frames"] == len(dropped) == stats["invalid_words"], stats
for i, ((valid, v, latch), (tv, tlatch)) in enumerate(zip(fr, truth)):
    assert latch == tlatch, (i, latch, tlatch)              # time-stamped at CS assertion
    assert valid == (i not in dropped), (i, valid)
    if valid and i not in flipped: assert v == tv, (i, v, tv)
    if valid and i in flipped: assert v != tv and bin(v ^ tv).count("1") == 1, (i, v, tv)
ok = [(v, latch) for valid, v, latch in fr if valid]
assert [v for v, _ in ok] == [v for _, v in sg], ("words differ from sigrok's", ok[:5], sg[:5])
# sigrok starts a word at its first sampling edge: the leading edge (CPHA 0), h samples after CS
# falls, or the trailing edge (CPHA 1), 2h after
for (v, latch), (ss, _) in zip(ok, sg):
    assert ss - latch == (2 * h if cpha else h), (latch, ss)
PY
      n=$((n + 1))
    done
  done
done

# SSI through sigrok's spi decoder: no CS, clock idle high, data read on the falling (leading)
# edge (CPOL 1, CPHA 0); a frame is B+1 falling edges, the first reading the ready level (1)
# at the latch. (sigrok's ssi32 decoder is another protocol: Bosch's SSI32 over SPI frames.)
for code in binary gray; do
  for bits in 1 13 25 32 63; do
    tag="ssi-$code-$bits"
    "$TOOL" emit ssi $bits $code 40 $((bits + 7)) "$dir/$tag.csv" > "$dir/$tag.truth"
    sigrok-cli -I "csv:column_formats=l,l:header=yes:samplerate=1000000" -i "$dir/$tag.csv" -o "$dir/$tag.sr"
    "$TOOL" decode ssi $bits $code "$dir/$tag.sr" > "$dir/$tag.fringe"
    sigrok-cli -i "$dir/$tag.sr" --protocol-decoder-samplenum \
      -P "spi:clk=clk:miso=data:cpol=1:cpha=0:wordsize=$((bits + 1)):bitorder=msb-first" -A spi=miso-data > "$dir/$tag.sigrok"
    $PY - "$dir/$tag" $bits $code <<'PY' || fail "$tag"
import json, sys
base, bits, code = sys.argv[1], int(sys.argv[2]), sys.argv[3]
truth = [tuple(map(int, l.split())) for l in open(base + ".truth")]
lines = open(base + ".fringe").read().splitlines()
stats = json.loads(lines[-1].split(" ", 1)[1])
fr = [tuple(map(int, l.split())) for l in lines[:-1]]
sg = []
for l in open(base + ".sigrok"):
    span, _, hexv = l.split()
    sg.append((int(span.split("-")[0]), int(hexv, 16)))
def gray_to_bin(g):
    b = 0
    while g: b ^= g; g >>= 1
    return b
assert stats["valid_words"] == len(truth) and stats["invalid_words"] == 0, stats
assert len(fr) == len(truth) == len(sg), (len(fr), len(truth), len(sg))
for (valid, v, latch), (tv, tlatch), (ss, w) in zip(fr, truth, sg):
    assert valid == 1 and v == tv and latch == tlatch, (v, tv, latch, tlatch)
    assert w >> bits == 1, ("the ready bit", hex(w))          # the first falling edge reads data high
    raw = w & ((1 << bits) - 1)
    assert (gray_to_bin(raw) if code == "gray" else raw) == v, (hex(w), v)
    assert ss == latch, (ss, latch)                            # the latch is the first falling edge
PY
    n=$((n + 1))
  done
done
echo "cli.position_words: ok ($n configurations agree with sigrok's spi decoder)"
