#!/usr/bin/env bash
# bench_oracle.sh BUILD - how much can orientation alone save, by
# PrusaSlicer's own verdict, and does our model rank the directions as
# PrusaSlicer does?  For every part of the sets asked for
# (tests/bench/valsets.sh; default "mech scad", the validation sets) the
# candidate up-directions are the six axis directions (CAD parts are
# axis-aligned) and, with ORACLE_DIRS=all (the default), the directions the
# direction search reshapes (optimize --method surface --search-direction 4
# --json: search.directions[].up; those within 2 degrees of an axis are left
# out).  Each candidate is the part turned so that direction points up
# (+z), the least rotation, resting on its lowest point; the turn is done by
# Debian's /usr/bin/python3 with numpy, independent of our code (the CLI has
# no option to turn a part to a given up).  +z is the file as given.  Each is
# sliced by PrusaSlicer (../shared/peers, 45 deg, supports on; rows cached by
# the STL's md5 in PEER_CACHE, as bench_supgrams.sh does; nice -n 19) for
# support grams and estimated print time, and scored by the direction
# search's own objective (bench_supmodel's last two columns: the steering
# model's grams and the print-time estimate's seconds, printtime.h) on the
# part as given with that up.  The search's own result (reshaped) is sliced
# too.
# Per part, one row per candidate (PS_g PS_h, model_g model_h), then:
#   given    the part as uploaded (+z)
#   search   the search's result (its reshaped part)
#   ps_g     PrusaSlicer's best by grams among the candidates that print no
#            more than 2 % slower than given (ties: the faster)
#   ps_t     PrusaSlicer's fastest candidate
#   mod_g    the candidate our model picks by the same rule on its own
#            figures (least model grams among those whose model seconds are
#            within 2 % of given), judged by PrusaSlicer
#   mod_t    our model's fastest, judged by PrusaSlicer
#   mod_v    (totals only) an approximation of the search's own rule over these
#            candidates unreshaped: no more model grams nor seconds than given,
#            then the least seconds + 60 s a gram (printtime.h's gram_s); it
#            leaves out dirsearch_pick's tie rule (within 2 % of time the fewer
#            grams), its reshape-must-pay rule and printtime_worth's margin
#   srch_v   (totals only) the search's result or mod_v, whichever the
#            model values less: a search that also weighed these candidates
#   ps_gx    (totals only) PrusaSlicer's least grams, however slow
# and "agree" flags: our pick is PrusaSlicer's, or PrusaSlicer puts them
# within its noise (2 % + 0.05 g of grams and 2 % of time for _g, 2 % of
# time for _t).  Each set ends with totals per choice (grams, hours, %
# against given) and the parts our model mis-ranks.  The turned parts live
# in ORACLE_OUT (default build/oracle)/PART-MD5/, the search's results and
# JSON under build/oracle/search-KEY (KEY: md5 of the CLI and its libexec
# commands).  ORACLE_SET="mech" picks sets, ORACLE_MESHES="hook clip"
# limits the parts, ORACLE_DIRS=axes skips the search, ORACLE_CACHED_ONLY=1
# reports cached peer rows only.  Skips cleanly without ../shared/peers
# (SLIMFARM_SHARED moves it) or a set that cannot be made (openscad).
set -u
build=${1:-build/rel}
here=$(cd "$(dirname "$0")" && pwd)
shared=${SLIMFARM_SHARED:-../shared}
[ -d "$shared/peers" ] || { echo "bench_oracle: $shared/peers absent, skipped"; exit 0; }
peers="$(cd "$shared" && pwd)/peers/slice-peers.sh"
py=/usr/bin/python3
for need in "$build/bin/slimfarm" "$build/bench/bench_supmodel"; do
  [ -x "$need" ] || { echo "bench_oracle: $need missing (make -j2 all), skipped"; exit 0; }
done
command -v prusa-slicer > /dev/null || { echo "bench_oracle: prusa-slicer missing (make bench installs it), skipped"; exit 0; }
"$py" -c 'import numpy' 2> /dev/null || { echo "bench_oracle: $py has no numpy (apt-get install python3-numpy), skipped"; exit 0; }
# shellcheck disable=SC2086
meshes=$("$here/valsets.sh" ${ORACLE_SET:-mech scad})
[ -n "$meshes" ] || { echo "bench_oracle: no meshes in set ${ORACLE_SET:-mech scad}, skipped"; exit 0; }
cache=${PEER_CACHE:-build/peercache}
sf="$build/bin/slimfarm"
out=${ORACLE_OUT:-build/oracle}
sdir="$out/search-$(cat "$sf" "$build"/libexec/slimfarm/* 2> /dev/null | md5sum | cut -c1-8)"
mkdir -p "$cache/stl" "$sdir"
rows=$(mktemp) # set part tag ux uy uz PS_g PS_s model_g model_s
work=$(mktemp -d)
trap 'rm -rf "$rows" "$work"' EXIT
# peer FILE -> "support_g est_time_s" by PrusaSlicer (cached by content)
peer() {
  local sum row; sum=$(md5sum < "$1" | cut -c1-32); row="$cache/stl/$sum.prusaslicer.csv"
  if [ ! -s "$row" ] && [ -z "${ORACLE_CACHED_ONLY:-}" ]; then
    PEER_RUNS=prusaslicer:on PEER_TIMEOUT=${PEER_TIMEOUT:-900} nice -n 19 "$peers" "$1" --format csv > "$row.tmp" 2> /dev/null &&
      mv "$row.tmp" "$row"
  fi
  awk -F, 'NR == 2 { print ($8 == 0 ? $14 " " $15 : "- -") }' "$row" 2> /dev/null | grep . || echo "- -"
}
# turn SRC DIR DIRS: DIR/TAG.stl for every "tag ux uy uz" line of DIRS
turn() {
  "$py" - "$@" << 'PYEOF'
import struct, sys
import numpy as np
src, out, dirs = sys.argv[1:4]
raw = open(src, "rb").read()
cnt = struct.unpack_from("<I", raw, 80)[0] if len(raw) >= 84 else 0
if len(raw) == 84 + 50 * cnt:
    rec = np.frombuffer(raw, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), count=cnt, offset=84)
    v = rec["v"].astype(np.float64)
else:  # ASCII STL
    pts = [list(map(float, l.split()[1:4])) for l in raw.decode("ascii", "replace").splitlines() if l.strip().startswith("vertex")]
    if not pts or len(pts) % 3:
        sys.exit("bench_oracle: %s: neither binary nor ASCII STL" % src)
    v = np.array(pts).reshape(-1, 3, 3)
for line in open(dirs):
    tag, *u = line.split()
    u = np.array(list(map(float, u))); u /= np.linalg.norm(u)
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
    o = np.zeros(len(w), dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
    o["n"] = nrm / ln; o["v"] = w
    with open("%s/%s.stl" % (out, tag), "wb") as fh:
        fh.write(b"bench_oracle".ljust(80, b" ") + struct.pack("<I", len(w)) + o.tobytes())
PYEOF
}
printf '%-14s %-6s %21s | %7s %6s | %8s %7s\n' part dir up PS_g PS_h model_g model_h
while IFS=$'\t' read -r set f; do
  name=$(basename "$f" .stl)
  [ -n "${ORACLE_MESHES:-}" ] && [[ " $ORACLE_MESHES " != *" $name "* ]] && continue
  md5=$(md5sum < "$f" | cut -c1-32)
  d="$out/$name-${md5:0:8}"; mkdir -p "$d"
  printf '%s 0 0 1\n%s 0 0 -1\n%s 1 0 0\n%s -1 0 0\n%s 0 1 0\n%s 0 -1 0\n' +z -z +x -x +y -y > "$work/dirs"
  # keyed by the part's content too: a changed template or seed makes a new part of the same name
  js="$sdir/$name-${md5:0:8}.json" res="$sdir/$name-${md5:0:8}.stl"
  if [ "${ORACLE_DIRS:-all}" != axes ]; then
    [ -s "$js" ] || nice "$sf" optimize "$f" -o "$res" --method surface --search-direction 4 --json > "$js" ||
      { echo "bench_oracle: $name: the search failed" >&2; rm -f "$js" "$res"; }
    # the search's directions, those not within 2 degrees of an axis (nor of each other)
    [ -s "$js" ] && "$py" - "$js" >> "$work/dirs" << 'PYEOF'
import json, math, sys
d = json.load(open(sys.argv[1]))
kept = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]
for i, x in enumerate(d["search"]["directions"]):
    u = x["up"]; n = math.sqrt(sum(c * c for c in u)); u = [c / n for c in u]
    if all(sum(a * b for a, b in zip(u, k)) < math.cos(math.radians(2)) for k in kept):
        kept.append(u); print("s%d %.9f %.9f %.9f" % (i + 1, *u))
PYEOF
  fi
  # turn what is not turned yet (the directions of a rebuilt search may differ: key by them)
  while read -r tag ux uy uz; do
    [ "$tag" = +z ] && continue
    key=$(printf '%.6f %.6f %.6f' "$ux" "$uy" "$uz" | md5sum | cut -c1-8)
    [ -s "$d/$tag-$key.stl" ] || { echo "$tag-$key $ux $uy $uz" >> "$work/turn"; }
  done < "$work/dirs"
  [ -s "$work/turn" ] && { turn "$f" "$d" "$work/turn" || exit 1; rm -f "$work/turn"; }
  "$build/bench/bench_supmodel" "$f" <(awk '{ print NR, $2, $3, $4 }' "$work/dirs") > "$work/model" ||
    { echo "bench_oracle: $name: bench_supmodel failed: no model figures" >&2; : > "$work/model"; }
  n=0
  while read -r tag ux uy uz; do
    n=$((n + 1))
    if [ "$tag" = +z ]; then stl=$f; else
      stl="$d/$tag-$(printf '%.6f %.6f %.6f' "$ux" "$uy" "$uz" | md5sum | cut -c1-8).stl"
    fi
    read -r g t < <(peer "$stl")
    read -r mg ms < <(awk -v n="$n" '$1 == n { print $7, $8 }' "$work/model")
    echo "$set $name $tag $ux $uy $uz $g $t ${mg:--} ${ms:--}" >> "$rows"
  done < "$work/dirs"
  if [ -s "$res" ] && [ -s "$js" ]; then
    read -r g t < <(peer "$res")
    mg=$("$py" -c 'import json,sys; r=json.load(open(sys.argv[1]))["search"]["result"]; print("%.3f %.1f" % (r["model_support_g"], r["print_s"]))' "$js" 2> /dev/null || echo "- -")
    echo "$set $name search 0 0 0 $g $t $mg" >> "$rows"
  fi
  awk -v p="$name" '$2 == p { printf "%-14s %-6s %6.3f,%6.3f,%6.3f | %7s %6s | %8s %7s\n", $2, $3, $4, $5, $6, $7,
    ($8 == "-" ? "-" : sprintf("%.2f", $8 / 3600)), $9, ($10 == "-" ? "-" : sprintf("%.2f", $10 / 3600)) }' "$rows"
done <<< "$meshes"
"$py" "$here/oracle_sum.py" "$rows"
