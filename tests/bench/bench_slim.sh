#!/usr/bin/env bash
# bench_slim.sh BUILD - the slimming loop's phases on ~8k tets (armadillo, or
# a generated torus without ../shared), its callgrind instruction count, then
# the peer table: risky faces, MNDR, ANDR and support grams before/after from
# PrusaSlicer, CuraEngine and our own slicer (what the farm prints and pays
# for) on a few shared meshes at alpha = 0 and 45 degrees.
# Env: SLIM_MESHES (names in ../shared/meshes, default "dino cow elephant");
# PEER_YAWS (default "0"): yaw angles in degrees about the build direction at
# which each part is sliced by the peers; with more than one the peer columns
# give the mean and the range.  A yaw changes no overhang, but PrusaSlicer's
# grid-style support snaps each layer's support to an axis-aligned grid, so
# its grams move by several percent with the part's yaw alone (dino at 0
# degrees: 21.38-22.93 g over seven yaws); one yaw is one sample of that.
# SLIM_ITERS (e.g. "3 8"): also the iterate at these iteration caps, each
# returned whatever it saves (--iterations N --min-gain 0), at alpha 45 only:
# do the peers see a saving part-way through that the last iterate loses?
# SLIM_ORIENTED=1: each mesh is first oriented for the angle (slimfarm orient
# --angle A), as the farm's --method slim does, and the oriented part is the
# input of the row.
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
yaws=${PEER_YAWS:-0}
# yaw FILE DEG OUT: FILE (binary STL) turned DEG degrees about z
yaw() {
  python3 - "$@" <<'EOF'
import math, struct, sys
src, deg, dst = sys.argv[1], float(sys.argv[2]), sys.argv[3]
d = open(src, "rb").read()
n = struct.unpack("<I", d[80:84])[0]
if len(d) != 84 + 50 * n:
    sys.exit("%s: not a binary STL" % src)
c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
out = bytearray(d[:84])
for i in range(n):
    v = list(struct.unpack("<12f", d[84 + 50 * i:132 + 50 * i]))
    for k in (0, 3, 6, 9):
        v[k], v[k + 1] = c * v[k] - s * v[k + 1], s * v[k] + c * v[k + 1]
    out += struct.pack("<12f", *v) + d[132 + 50 * i:134 + 50 * i]
open(dst, "wb").write(out)
EOF
}
# support grams of one slicer ($3: prusaslicer or curaengine; CuraEngine is the second opinion:
# no interface layers, no sheath, so it follows column volume more closely than PrusaSlicer),
# at each yaw of PEER_YAWS: one figure, or "mean (min-max)"
grams() {
  local y f all=""
  for y in $yaws; do
    f=$1
    if [ "$y" != 0 ]; then f="$work/yaw.stl"; yaw "$1" "$y" "$f" || return; fi
    all="$all $(PEER_RUNS=$3:on "$peers" "$f" --angle "$2" --format csv | awk -F, 'NR == 2 { print $14 }')"
  done
  echo "$all" | awk '{ if (NF == 1) { print $1; exit }
    lo = hi = $1; for (i = 1; i <= NF; i++) { s += $i; lo = $i < lo ? $i : lo; hi = $i > hi ? $i : hi }
    printf "%.2f (%.2f-%.2f)\n", s / NF, lo, hi }'
}
# support grams of our slicer at this overhang angle (support_angle 0 means "the printer's
# own", so the angle is given as the printer's max_overhang)
ours() { "$build/bin/slimfarm" slice "$1" -o "$work/ours.gcode" --set max_overhang="$2" 2>&1 |
  sed -n 's/.*(support \([0-9.]*\) g).*/\1/p'; }
echo "peer yaws: $yaws"
echo "| mesh | alpha | risky before -> after | MNDR % | ANDR % | part volume % | support mm3 before -> after | PS support g before -> after | CE support g before -> after | ours support g before -> after | s |"
echo "|---|---|---|---|---|---|---|---|---|---|---|"
for name in ${SLIM_MESHES:-dino cow elephant}; do
  for run in 0 45 ${SLIM_ITERS:+$(printf '45@%s ' $SLIM_ITERS)}; do
    angle=${run%@*} label=$run cap=()
    [ "$run" != "$angle" ] && cap=(--iterations "${run#*@}" --min-gain 0) label="$angle (${run#*@} iterations)"
    in=../shared/meshes/$name.stl out="$work/$name-$angle.stl"
    if [ "${SLIM_ORIENTED:-0}" = 1 ]; then
      "$build/bin/slimfarm" orient "$in" -o "$work/$name-oriented-$angle.stl" --angle "$angle" >/dev/null ||
        { echo "| $name | $label | orient failed |"; continue; }
      in="$work/$name-oriented-$angle.stl"
    fi
    js=$("$build/bin/slimfarm" optimize "$in" -o "$out" --method volumetric --angle "$angle" "${cap[@]}" --json) || { echo "| $name | $label | failed |"; continue; }
    row=$(python3 -c 'import json,sys; j=json.loads(sys.argv[1]); b,a,d=j["before"],j["after"],j["deviation"]
v=j["part_volume_mm3"]
print("%d -> %d | %.1f | %.1f | %+.1f | %.0f -> %.0f | %.1f" % (b["risky_faces"], a["risky_faces"], 100*d["mndr"], 100*d["andr"], 100*(v["after"]/v["before"]-1), b["support_volume_mm3"], a["support_volume_mm3"], j["seconds"]))' "$js")
    if [ "$name $angle" != "${sliced_in:-}" ]; then # the input's grams, once per mesh and angle
      g0=$(grams "$in" "$angle" prusaslicer) c0=$(grams "$in" "$angle" curaengine) o0=$(ours "$in" "$angle")
      sliced_in="$name $angle"
    fi
    g1=$(grams "$out" "$angle" prusaslicer) c1=$(grams "$out" "$angle" curaengine) o1=$(ours "$out" "$angle")
    secs=${row##*| }; row=${row% | *}
    echo "| $name | $label | $row | $g0 -> $g1 | $c0 -> $c1 | $o0 -> $o1 | $secs |"
  done
done
