#!/usr/bin/env bash
# bench_suplayers.sh - the bench's per-layer support (tests/bench/valsets/
# suplayers.py) on two G-codes written here, in CuraEngine's words: A prints
# a column of support, 4 x 2 mm, on layers 0.2-1.0 (absolute E, a retraction
# and a prime between its lines, the part's wall under another role); B
# prints the same and a second column on layers 0.2-0.6 beside it, in
# relative E.  A alone lists its 5 layers with 1.0 mm of filament each; A
# against B lists the 3 layers where B adds the column, and no other.
# Env: BUILD (unused: the measure is Python alone).
set -u
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 - "$work" <<'PY'
import sys
def gcode(rel, towers):
    out = ["M83" if rel else "M82", "G92 E0"]
    e = 0.0
    def ext(x, y, d):
        nonlocal e
        e += d
        out.append("G1 X%.2f Y%.2f E%.4f" % (x, y, d if rel else e))
    for k in range(5):
        out.append(";LAYER:%d" % k)
        out.append("G0 Z%.2f" % (0.2 * (k + 1)))
        out.append(";TYPE:WALL-OUTER")
        out.append("G0 X100 Y100")
        ext(110, 100, 0.7)
        out.append(";TYPE:SUPPORT")
        out.append("G0 X120 Y100")
        ext(124, 100, 0.25)
        out.append("G1 E%.4f" % (-1 if rel else e - 1))  # retraction: not support
        out.append("G1 E%.4f" % (1 if rel else e))  # prime
        out.append("G0 X120 Y102")
        ext(124, 102, 0.75)
        if towers and k < 3:
            out.append("G0 X130 Y100")
            ext(130, 103, 0.3)
    return "\n".join(out) + "\n"
open(sys.argv[1] + "/a.gcode", "w").write(gcode(False, False))
open(sys.argv[1] + "/b.gcode", "w").write(gcode(True, True))
PY
fail=0
one=$(python3 tests/bench/valsets/suplayers.py "$work/a.gcode") || { echo "suplayers failed on A"; exit 1; }
echo "$one"
[ "$(grep -c '^z=' <<<"$one")" = 5 ] || { echo "A: want 5 layers of support"; fail=1; }
grep -q '^z=0.60 support=1.000 x=120.00..124.00 y=100.00..102.00$' <<<"$one" ||
  { echo "A: want 1.0 mm of support in a 4 x 2 mm box at z 0.6 (retraction, prime and wall left out)"; fail=1; }
grep -q '^total support=5.000 layers=5$' <<<"$one" || { echo "A: want 5.0 mm on 5 layers"; fail=1; }
two=$(python3 tests/bench/valsets/suplayers.py "$work/a.gcode" "$work/b.gcode") ||
  { echo "suplayers failed on A and B"; exit 1; }
echo "$two"
[ "$(grep -c '^z=' <<<"$two")" = 3 ] || { echo "A against B: want the 3 layers B adds to, no other"; fail=1; }
grep -q '^z=0.20 | support=1.000 x=120.00..124.00 .* | support=1.300 x=120.00..130.00 y=100.00..103.00$' <<<"$two" ||
  { echo "A against B: want B's layer 0.2 with the second column (1.3 mm, box out to x 130)"; fail=1; }
grep -q '^total support=5.000 layers=5 | support=5.900 layers=5$' <<<"$two" || { echo "A against B: want totals 5.0 and 5.9 mm"; fail=1; }
exit $fail
