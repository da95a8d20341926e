#!/usr/bin/env bash
# bench_thin.sh BUILD - thin parts against PrusaSlicer 2.5 (shared/peers):
# generated 40 mm discs standing on their edge, 2, 2.5 and 3 mm thick (every
# layer a strip too narrow for ordinary infill beside the perimeters), and
# 20 x 10 mm walls 0.4-3 mm thick.  One row per part: the part's volume as
# filament, ours, PrusaSlicer's and the ratio, and our filament by role.
# Supports off, no skirt or brim, like the peers.  PrusaSlicer's rows are
# cached under ${PEER_CACHE:-build/peercache}/thin (written to a temporary
# name, then moved into place).  BENCH_PEERS=0: ours only.
set -u
build=${1:-build/rel}
shared=${SLIMFARM_SHARED:-../shared}
bin="$build/bin/slimfarm"
py=/usr/bin/python3
[ -x "$bin" ] || { echo "bench_thin: $bin not built"; exit 1; }
peers=${BENCH_PEERS:-1}
if [ "$peers" = 1 ] && { [ ! -f "$shared/peers/slice-peers.sh" ] || ! command -v prusa-slicer >/dev/null; }; then
  echo "bench_thin: no PrusaSlicer or $shared/peers; ours only"; peers=0
fi
cache=${PEER_CACHE:-build/peercache}/thin
mkdir -p "$cache"
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT

# part NAME KIND SIZE: write $work/NAME.stl, print its volume as filament mm
part() {
  "$py" - "$work/$1.stl" "$2" "$3" <<'PY'
import math, struct, sys
out, kind, t = sys.argv[1], sys.argv[2], float(sys.argv[3])
if kind == "disc":   # radius 20 in xz, axis along y, standing on its edge
    n = 128
    prof = [(20 * math.cos(2 * math.pi * i / n), 20 + 20 * math.sin(2 * math.pi * i / n)) for i in range(n)]
else:                # wall: t thick in x, 20 long in y, 10 high; profile in xz, depth along y
    prof, t = [(0, 0), (t, 0), (t, 10), (0, 10)], 20.0
tris = []
c = (sum(p[0] for p in prof) / len(prof), sum(p[1] for p in prof) / len(prof))
for i in range(len(prof)):
    a, b = prof[i], prof[(i + 1) % len(prof)]
    A0, B0, A1, B1 = (a[0], 0, a[1]), (b[0], 0, b[1]), (a[0], t, a[1]), (b[0], t, b[1])
    tris += [(A0, A1, B1), (A0, B1, B0), ((c[0], 0, c[1]), A0, B0), ((c[0], t, c[1]), B1, A1)]
with open(out, "wb") as f:
    f.write(b"bench_thin".ljust(80, b" ") + struct.pack("<I", len(tris)))
    for tri in tris:
        f.write(struct.pack("<12fH", 0, 0, 0, *tri[0], *tri[1], *tri[2], 0))
area = abs(sum(prof[i][0] * prof[(i + 1) % len(prof)][1] - prof[(i + 1) % len(prof)][0] * prof[i][1]
               for i in range(len(prof)))) / 2
print("%.1f" % (area * t / (math.pi * 1.75 ** 2 / 4)))
PY
}
# roles FILE: "role=mm ..." of positive E on XY moves (absolute E, G92 resets)
roles() {
  awk '/^;TYPE:/ { t = substr($0, 7); gsub(/ /, "_", t); next }
    /^G92/ { e = 0; next }
    /^G[0-3] / { n = split($0, f, " "); xy = 0; has = 0
      for (i = 2; i <= n; i++) { c = substr(f[i], 1, 1); if (c == "X" || c == "Y") xy = 1
        else if (c == "E") { E = substr(f[i], 2) + 0; has = 1 } }
      if (has) { if (xy && E > e) s[t] += E - e; e = E } }
    END { for (k in s) printf "%s=%.0f ", k, s[k] }' "$1"
}
printf '| part | volume mm | ours mm | PS mm | ours/PS | ours by role |\n|---|---|---|---|---|---|\n'
for spec in disc:2 disc:2.5 disc:3 wall:0.4 wall:0.6 wall:1 wall:2 wall:2.5 wall:3; do
  kind=${spec%%:*} size=${spec#*:} name="${spec/:/}"
  vol=$(part "$name" "$kind" "$size")
  "$bin" slice "$work/$name.stl" -o "$work/$name.gcode" --no-support --set skirts=0 \
    --set brim_auto=no >/dev/null 2>&1 || { echo "| $name | slice failed |"; continue; }
  ours=$(sed -n 's/^; filament used \[mm\] = //p' "$work/$name.gcode" | head -n 1)
  ps=0
  if [ "$peers" = 1 ]; then
    row="$cache/$name.prusaslicer.csv"
    if [ ! -s "$row" ]; then
      PEER_RUNS=prusaslicer:off nice -n 19 bash "$shared/peers/slice-peers.sh" "$work/$name.stl" \
        --format csv 2>/dev/null | tail -n 1 > "$row.tmp.$$" && mv "$row.tmp.$$" "$row"
    fi
    ps=$(cut -d, -f11 "$row" 2>/dev/null)
  fi
  awk -v n="$name" -v v="$vol" -v o="$ours" -v p="${ps:-0}" -v r="$(roles "$work/$name.gcode")" \
    'BEGIN { printf "| %s | %.1f | %.1f | %.1f | %s | %s |\n", n, v, o, p, (p > 0 ? sprintf("%.3f", o / p) : "-"), r }'
done
