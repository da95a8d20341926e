#!/usr/bin/env bash
# bench_gcstats.sh - the bench's skin measure (tests/bench/valsets/gcstats.py)
# on a G-code written here: a 20 x 20 mm slab on one layer of support, a
# 4 x 4 mm post beside it standing on the bed (so the support's layer is
# one of the part's).  The slab prints 3 solid layers at its bottom, sparse
# infill (lines 5 mm apart, along y, then along x), a band of 2 solid layers
# inside, sparse again, and 4 solid layers at its top.  The skins are the
# 3 bottom and 4 top layers: 0.60 and 0.80 mm.  The band is no skin, though
# where the lines below pass by a 1 mm cell and those above cross it, the
# cell shows solid over nothing and under sparse infill; a bottom over
# support is one, though the support marks the cell below.
# Env: BUILD (unused: the measure is Python alone).
set -u
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 - "$work/slab.gcode" <<'PY'
import sys
out = ["M83"]
def role(r):
    out.append(";TYPE:" + r)
def path(pts, e=0.05):
    out.append("G1 X%.3f Y%.3f" % pts[0])
    for p in pts[1:]:
        out.append("G1 X%.3f Y%.3f E%.4f" % (p[0], p[1], e))
def square(x0, y0, x1, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
def lines_x(x0, x1, ys):
    for y in ys:
        path([(x0, y), (x1, y)])
def lines_y(y0, y1, xs):
    for x in xs:
        path([(x, y0), (x, y1)])
solid = [101 + 0.45 * k for k in range(40)]
sparse = [102.5, 107.5, 112.5, 117.5]
for k in range(15):
    out.append("G1 Z%.2f" % (0.2 * (k + 1)))
    role("External perimeter")  # the post: all layers, solid
    path(square(130.5, 130.5, 133.5, 133.5))
    role("Solid infill")
    lines_x(131, 133, [131, 131.5, 132, 132.5, 133])
    if k == 0:
        role("Support material")
        lines_x(100, 120, [100 + 2 * q for q in range(11)])
        continue
    role("External perimeter")
    path(square(100.5, 100.5, 119.5, 119.5))
    if k in (1, 2, 3, 7, 8, 11, 12, 13, 14):
        role("Solid infill")
        lines_x(101, 119, solid)
    else:
        role("Internal infill")
        (lines_y(101, 119, sparse) if k < 7 else lines_x(101, 119, sparse))
open(sys.argv[1], "w").write("\n".join(out) + "\n")
PY
stats=$(python3 tests/bench/valsets/gcstats.py "$work/slab.gcode") || { echo "gcstats failed"; exit 1; }
echo "   $stats"
fail=0
grep -q ' top=0.80 ' <<<"$stats" || { echo "top skin: want 0.80 mm (4 layers)"; fail=1; }
grep -q ' bottom=0.60 ' <<<"$stats" || { echo "bottom skin: want 0.60 mm (3 layers over the support)"; fail=1; }
exit $fail
