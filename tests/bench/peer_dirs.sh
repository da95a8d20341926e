#!/usr/bin/env bash
# peer_dirs.sh SLICER [N] - slice every shared mesh turned onto N (default 64)
# Fibonacci-sphere up-directions with one peer slicer (prusaslicer or
# curaengine, supports on, 45 deg) and keep one result row a direction in the
# repo, tests/bench/peerdata/dirsN/MESH.SLICER.csv (PEER_DATA=DIR moves it):
#   mesh,mesh_md5,i,ux,uy,uz,slicer,version,support_g,est_time_s,rc,wall_s
# mesh_md5 is the md5 of the source STL, i the direction's index and
# (ux,uy,uz) the up-direction turned onto +z, support_g and est_time_s the
# peer's support grams and estimated print time (slice-peers.sh), rc its exit
# code and wall_s its seconds.  Directions already in the file with this md5
# are skipped, rows of another md5 (a changed mesh) are dropped and the
# direction sliced again; each new row is appended as soon as it is done, so
# the rows accumulate across sessions: commit the file.  A timed-out run
# (rc 124: a loaded machine) leaves no row and is tried again next time.
# The turned parts (python rotation, independent of our code) live in
# ${PEER_CACHE:-build/peercache}/dirsN/MESH-MD5/I.stl, never in the repo.  The
# peers run under nice -n 19: the machine is shared.  Read by
# bench_supmodel.sh.
# PEER_MESHES="anchor dino" limits the meshes and gives their order (default:
# all, smallest first).  The directions go in bit-reversed order, a quarter of
# them for every mesh before the next quarter, so a run stopped early still
# has well-spread directions on every mesh.  PEER_LIMIT=K stops after the
# first K directions of that order on every mesh (default: all n).
set -u
slicer=${1:?usage: peer_dirs.sh prusaslicer|curaengine [N]}
n=${2:-64}
shared=${SLIMFARM_SHARED:-../shared}
[ -d "$shared/meshes" ] || { echo "peer_dirs: $shared/meshes absent, skipped"; exit 0; }
peers="$(cd "$shared" && pwd)/peers/slice-peers.sh"
cache=${PEER_CACHE:-build/peercache}/dirs$n
data=${PEER_DATA:-$(dirname "$0")/peerdata}/dirs$n
head=mesh,mesh_md5,i,ux,uy,uz,slicer,version,support_g,est_time_s,rc,wall_s
py=/usr/bin/python3
mkdir -p "$data"
if [ -n "${PEER_MESHES:-}" ]; then
  meshes=$(for m in $PEER_MESHES; do echo "$shared/meshes/$m.stl"; done)
else
  meshes=$(ls -S -r "$shared"/meshes/*.stl)
fi
for f in $meshes; do
  name=$(basename "$f" .stl)
  md5=$(md5sum < "$f" | cut -c1-32)
  rows="$data/$name.$slicer.csv"
  # keep the header and this mesh's rows (another md5: the mesh changed)
  if [ -s "$rows" ]; then
    awk -F, -v m="$md5" -v h="$head" 'NR == 1 { print h; next } $2 == m' "$rows" > "$rows.tmp" &&
      { cmp -s "$rows" "$rows.tmp" || cp "$rows.tmp" "$rows"; rm -f "$rows.tmp"; }
  else
    echo "$head" > "$rows"
  fi
  d="$cache/$name-$md5"; mkdir -p "$d"
  # the turned parts: rotation taking direction i onto +z (Rodrigues, least turn)
  [ -f "$d/dirs.txt" ] || "$py" - "$f" "$d" "$n" <<'PYEOF' || exit 1
import math, struct, sys
import numpy as np
src, out, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
raw = open(src, "rb").read()
cnt = struct.unpack_from("<I", raw, 80)[0]
rec = np.frombuffer(raw, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), count=cnt, offset=84)
v = rec["v"].astype(np.float64)
golden = math.pi * (3 - math.sqrt(5))
lines = []
for i in range(n):
    z = 1 - (2 * i + 1) / n
    r = math.sqrt(max(0.0, 1 - z * z))
    u = np.array([r * math.cos(golden * i), r * math.sin(golden * i), z])
    lines.append("%d %.9f %.9f %.9f" % (i, *u))
    k = np.cross(u, [0, 0, 1.0]); s = np.linalg.norm(k); c = u[2]
    if s < 1e-12:
        R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        k /= s
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + s * K + (1 - c) * K @ K
    w = v @ R.T
    w[:, :, 2] -= w[:, :, 2].min()
    nrm = np.cross(w[:, 1] - w[:, 0], w[:, 2] - w[:, 0])
    ln = np.linalg.norm(nrm, axis=1, keepdims=True); ln[ln == 0] = 1
    o = np.zeros(cnt, dtype=rec.dtype)
    o["n"] = nrm / ln; o["v"] = w
    with open("%s/%d.stl" % (out, i), "wb") as fh:
        fh.write(b"peer_dirs".ljust(80, b" ") + struct.pack("<I", cnt) + o.tobytes())
open(out + "/dirs.txt", "w").write("\n".join(lines) + "\n")
PYEOF
done
# bit-reversed order of 0..n-1 (n a power of two; other n: plain order)
order=$(awk -v n="$n" 'BEGIN { b = 0; while (2 ^ b < n) b++; if (2 ^ b != n) { for (i = 0; i < n; i++) print i; exit }
  for (i = 0; i < n; i++) { r = 0; x = i; for (k = 0; k < b; k++) { r = r * 2 + x % 2; x = int(x / 2) } print r } }')
[ -n "${PEER_LIMIT:-}" ] && order=$(echo "$order" | head -n "$PEER_LIMIT")
quarter=$(( (n + 3) / 4 ))
for ((q = 0; q < 4; q++)); do
  part=$(echo "$order" | sed -n "$((q * quarter + 1)),$(((q + 1) * quarter))p")
  for f in $meshes; do
    name=$(basename "$f" .stl)
    md5=$(md5sum < "$f" | cut -c1-32)
    rows="$data/$name.$slicer.csv" d="$cache/$name-$md5"
    for i in $part; do
      awk -F, -v m="$md5" -v i="$i" 'NR > 1 && $2 == m && $3 == i { found = 1; exit } END { exit !found }' "$rows" && continue
      out=$(PEER_RUNS=$slicer:on PEER_TIMEOUT=${PEER_TIMEOUT:-900} nice -n 19 "$peers" "$d/$i.stl" --format csv 2>/dev/null |
        awk -F, 'NR == 2 { print $5 "," $14 "," $15 "," $8 "," $9 }')  # version,support_g,est_time_s,rc,wall_s
      [ -n "$out" ] || continue
      [ "$(echo "$out" | cut -d, -f4)" = 124 ] && continue  # timed out: try again next time
      u=$(awk -v i="$i" '$1 == i { print $2 "," $3 "," $4 }' "$d/dirs.txt")
      echo "$name,$md5,$i,$u,$slicer,$out" >> "$rows"
    done
  done
  echo "peer_dirs: $slicer quarter $((q + 1)) done"
done
