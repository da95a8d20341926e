#!/usr/bin/env bash
# bench_supmodel.sh BUILD - how well the layer-based support model ranks
# up-directions the way the peer slicers do.  For every shared mesh with
# cached peer runs (tests/bench/peer_dirs.sh, 64 Fibonacci directions under
# build/peercache/dirs64), the Spearman rank correlation over the directions
# of PrusaSlicer's and CuraEngine's support grams with: our model imitating
# that slicer (supmodel.h), today's ray-cast support volume at 45 degrees
# and at 40 (orient's 5-degree margin).  Also the model's milliseconds per
# direction (cast included) against one ray-cast measure_support.
# SUPMODEL_PITCH=MM sets the model's raster (default 0.5).  Without the
# cache (run peer_dirs.sh first: it takes hours) the script says so and exits.
set -u
build=${1:-build/rel}
cache=${PEER_CACHE:-build/peercache}/dirs${SUPMODEL_DIRS:-64}
shared=${SLIMFARM_SHARED:-../shared}
[ -d "$shared/meshes" ] || { echo "bench_supmodel: $shared/meshes absent, skipped"; exit 0; }
[ -d "$cache" ] || { echo "bench_supmodel: no peer cache in $cache (tests/bench/peer_dirs.sh prusaslicer), skipped"; exit 0; }
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
printf '%-17s %4s %4s | %8s %8s %8s | %8s %8s %8s | %8s %8s\n' mesh n_ps n_ce \
  ps~model ps~ray45 ps~ray40 ce~model ce~ray45 ce~ray40 model_ms ray_ms
for d in "$cache"/*/; do
  name=$(basename "$d")
  [ -f "$d/dirs.txt" ] || continue
  ls "$d" | grep -q '\.csv$' || continue  # no peer row yet
  "$build/bench/bench_supmodel" "$shared/meshes/$name.stl" "$d/dirs.txt" ${SUPMODEL_PITCH:-} > "$work/m.txt" || continue
  for s in prusaslicer curaengine; do
    : > "$work/$s.txt"
    for f in "$d"/*."$s".csv; do
      [ -f "$f" ] || continue
      i=$(basename "$f" ".$s.csv")
      awk -F, -v i="$i" 'NR == 2 && $8 == 0 { print i, $14 }' "$f" >> "$work/$s.txt"
    done
  done
  /usr/bin/python3 - "$name" "$work" <<'PYEOF'
import sys
import numpy as np
name, work = sys.argv[1], sys.argv[2]
model, ms = {}, (0, 0)
for line in open(work + "/m.txt"):
    p = line.split()
    if p[0] == "#":
        ms = (float(p[2]), float(p[4]))
        continue
    model[int(p[0])] = [float(x) for x in p[1:]]
def ranks(v):
    v = np.asarray(v, float); o = np.argsort(v, kind="stable"); r = np.empty(len(v))
    r[o] = np.arange(len(v)); 
    for u in np.unique(v):  # average ties
        k = v == u; r[k] = r[k].mean()
    return r
def rho(a, b):
    if len(a) < 3: return float("nan")
    ra, rb = ranks(a), ranks(b)
    if ra.std() == 0 or rb.std() == 0: return float("nan")
    return float(np.corrcoef(ra, rb)[0, 1])
cols, ns = [], []
for s, mi in (("prusaslicer", 0), ("curaengine", 1)):
    peer = {}
    for line in open("%s/%s.txt" % (work, s)):
        i, g = line.split(); peer[int(i)] = float(g)
    ids = sorted(i for i in peer if i in model)
    ns.append(len(ids))
    pg = [peer[i] for i in ids]
    for col in (mi, 2, 3):
        cols.append(rho(pg, [model[i][col] for i in ids]))
print("%-17s %4d %4d | %8.3f %8.3f %8.3f | %8.3f %8.3f %8.3f | %8.1f %8.1f" % (name, ns[0], ns[1], *cols, *ms))
PYEOF
done
