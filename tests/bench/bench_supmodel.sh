#!/usr/bin/env bash
# bench_supmodel.sh BUILD - how well the layer-based support model ranks
# up-directions the way the peer slicers do.  For every shared mesh with peer
# rows in tests/bench/peerdata/dirs64/MESH.SLICER.csv (peer_dirs.sh writes
# them, format in its header; rows whose mesh_md5 is not the mesh's today are
# left out, as are failed runs), the Spearman rank correlation over the
# directions of PrusaSlicer's and CuraEngine's support grams with: our model
# imitating that slicer (supmodel.h), today's ray-cast support volume at 45
# degrees and at 40 (orient's 5-degree margin).  n_ps and n_ce count the
# directions.  Also the model's milliseconds per direction (cast included)
# against one ray-cast measure_support.  SUPMODEL_PITCH=MM sets the model's
# raster (default: the model's own, supmodel_params_default); PEER_DATA=DIR
# reads rows elsewhere.  Without rows
# (run peer_dirs.sh: it takes hours) the script says so and exits.
set -u
build=${1:-build/rel}
data=${PEER_DATA:-$(dirname "$0")/peerdata}/dirs${SUPMODEL_DIRS:-64}
shared=${SLIMFARM_SHARED:-../shared}
[ -d "$shared/meshes" ] || { echo "bench_supmodel: $shared/meshes absent, skipped"; exit 0; }
ls "$data"/*.csv > /dev/null 2>&1 || { echo "bench_supmodel: no peer rows in $data (tests/bench/peer_dirs.sh prusaslicer), skipped"; exit 0; }
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
printf '%-17s %4s %4s | %8s %8s %8s | %8s %8s %8s | %8s %8s\n' mesh n_ps n_ce \
  ps~model ps~ray45 ps~ray40 ce~model ce~ray45 ce~ray40 model_ms ray_ms
for mesh in "$shared"/meshes/*.stl; do
  name=$(basename "$mesh" .stl)
  md5=$(md5sum < "$mesh" | cut -c1-32)
  for s in prusaslicer curaengine; do  # "i grams" of this mesh's successful runs
    awk -F, -v m="$md5" 'NR > 1 && $2 == m && $11 == 0 { print $3, $9 }' "$data/$name.$s.csv" 2>/dev/null > "$work/$s.txt"
  done
  cat "$data/$name".*.csv 2>/dev/null | awk -F, -v m="$md5" '$2 == m && !seen[$3]++ { print $3, $4, $5, $6 }' > "$work/dirs.txt"
  [ -s "$work/prusaslicer.txt" ] || [ -s "$work/curaengine.txt" ] || continue  # no peer row yet
  "$build/bench/bench_supmodel" "$mesh" "$work/dirs.txt" ${SUPMODEL_PITCH:-} > "$work/m.txt" || continue
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
