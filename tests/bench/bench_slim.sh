#!/usr/bin/env bash
# bench_slim.sh BUILD - the slimming loop's phases on ~8k tets (armadillo, or
# a generated torus without ../shared), its callgrind instruction count, then
# the peer table: risky faces, MNDR, ANDR and PrusaSlicer support grams
# before/after on a few shared meshes at alpha = 0 and 45 degrees.
set -u
build=${1:-build/rel}
mesh=""
[ -f ../shared/meshes/armadillo.stl ] && mesh=../shared/meshes/armadillo.stl
"$build/bench/bench_slim" "$mesh"
if command -v valgrind >/dev/null; then
  out=$(mktemp)
  valgrind --tool=callgrind --callgrind-out-file="$out" "$build/bench/bench_slim" "$mesh" "" 1 >/dev/null 2>&1
  echo "callgrind, one run (setup + 100 iterations), instructions by phase (valgrind runs the"
  echo "  AVX2 clone: it does not emulate AVX-512; local_pass = gradients + nearest rotations + RHS):"
  callgrind_annotate --inclusive=yes "$out" 2>/dev/null |
    grep -E "PROGRAM TOTALS|:(polar_block[.a-z0-9_]*|local_pass[.a-z0-9_]*|arap_local|arap_global|sparse_chol_solve|minrot_solve|tetmesh_build) \[" |
    sed 's/^/  /'
  rm -f "$out"
fi
peers=../shared/peers/slice-peers.sh
[ -x "$peers" ] && [ -d ../shared/meshes ] || { echo "(no ../shared: peer table skipped)"; exit 0; }
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
# support grams of one slicer ($3: prusaslicer or curaengine; CuraEngine is the second opinion:
# no interface layers, no sheath, so it follows column volume more closely than PrusaSlicer)
grams() { PEER_RUNS=$3:on "$peers" "$1" --angle "$2" --format csv | awk -F, 'NR == 2 { print $14 }'; }
echo "| mesh | alpha | risky before -> after | MNDR % | ANDR % | support mm3 before -> after | PS support g before -> after | CE support g before -> after | s |"
echo "|---|---|---|---|---|---|---|---|---|"
for name in ${SLIM_MESHES:-dino cow elephant}; do
  for angle in 0 45; do
    in=../shared/meshes/$name.stl out="$work/$name-$angle.stl"
    js=$("$build/bin/slimfarm" optimize "$in" -o "$out" --method volumetric --angle "$angle" --json) || { echo "| $name | $angle | failed |"; continue; }
    row=$(python3 -c 'import json,sys; j=json.loads(sys.argv[1]); b,a,d=j["before"],j["after"],j["deviation"]
print("%d -> %d | %.1f | %.1f | %.0f -> %.0f | %.1f" % (b["risky_faces"], a["risky_faces"], 100*d["mndr"], 100*d["andr"], b["support_volume_mm3"], a["support_volume_mm3"], j["seconds"]))' "$js")
    g0=$(grams "$in" "$angle" prusaslicer) g1=$(grams "$out" "$angle" prusaslicer)
    c0=$(grams "$in" "$angle" curaengine) c1=$(grams "$out" "$angle" curaengine)
    secs=${row##*| }; row=${row% | *}
    echo "| $name | $angle | $row | $g0 -> $g1 | $c0 -> $c1 | $secs |"
  done
done
