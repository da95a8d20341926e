#!/usr/bin/env bash
# slice_mech.sh - three parts of the mech validation family
# (tests/bench/valsets.sh: OpenSCAD templates, parameters from the fixed
# seed) are generated and sliced with `slimfarm slice`: each loads as one
# closed, manifold solid of the modelled height, and its G-code has every
# layer, perimeters and extrusion; the lid uploaded lip-down and the box
# uploaded upside down print support, the same lid lip-up (a flat plate: only its
# snap beads overhang) under a quarter of the lip-down's (PrusaSlicer 2.5:
# 100 mm of support and interface lip-up, 608 mm lip-down).  Skips (passes)
# when openscad is not installed (make check installs it when it can).
# Env: BUILD (build dir, e.g. build/san).
set -u
build=${BUILD:-build/rel}
bin="$build/bin/slimfarm"
if ! command -v openscad >/dev/null; then
  echo "   skipped: openscad not installed (apt-get install openscad; make check tries to)"
  exit 0
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
parts="lid_down lid_up box_upside"
list=$(VALSET_DIR="$work/sets" VALSET_PARTS="$parts" tests/bench/valsets.sh mech 2>"$work/gen.err") || {
  echo "generating the mech parts failed: $(tail -n 3 "$work/gen.err")"; exit 1; }
fail=0
declare -A sup
for name in $parts; do
  stl=$(awk -F'\t' -v n="$name" '$2 ~ "/" n ".stl$" { print $2 }' <<<"$list")
  [ -s "$stl" ] || { echo "$name: not generated"; fail=1; continue; }
  info=$("$bin" inspect "$stl" 2>&1) || { echo "$name: inspect failed: $info"; fail=1; continue; }
  grep -q 'topology: *closed, 1 component, [0-9]* edges, 0 boundary, 0 non-manifold' <<<"$info" || {
    echo "$name: not one closed manifold solid: $(grep topology <<<"$info")"; fail=1; }
  height=$(sed -n 's/^ *size: *[0-9.]* x [0-9.]* x \([0-9.]*\) mm.*/\1/p' <<<"$info")
  out=$("$bin" slice "$stl" -o "$work/$name.gcode" 2>&1) || { echo "$name: slice failed: $out"; fail=1; continue; }
  layers=$(sed -n 's/.*: \([0-9]*\) layers.*/\1/p' <<<"$out")
  want=$(awk -v h="$height" 'BEGIN { printf "%d", h / 0.2 + 0.5 }')
  if [ -z "$layers" ] || [ $((layers - want)) -gt 1 ] || [ $((want - layers)) -gt 1 ]; then
    echo "$name: ${layers:-no} layers for a ${height:-?} mm part (want $want +- 1)"; fail=1
  fi
  stats=$(python3 tests/bench/valsets/gcstats.py "$work/$name.gcode")
  read -r ext solid support <<<"$(awk '{ for (i = 1; i <= NF; i++) { split($i, kv, "="); a[kv[1]] = kv[2] }
    print a["ext"], a["solid"] + a["infill"], a["support"] + a["iface"] }' <<<"$stats")"
  awk -v e="$ext" -v s="$solid" 'BEGIN { exit !(e > 0 && s > 0) }' || {
    echo "$name: no external perimeter or infill: $stats"; fail=1; }
  sup[$name]=$support
  echo "   $name: ${height} mm, $layers layers, support+interface ${support} mm of filament"
done
for name in lid_down box_upside; do
  awk -v s="${sup[$name]:-0}" 'BEGIN { exit !(s > 100) }' || {
    echo "$name: needs support, got ${sup[$name]:-none} mm"; fail=1; }
done
awk -v u="${sup[lid_up]:-x}" -v d="${sup[lid_down]:-0}" 'BEGIN { exit !(u != "x" && u < d / 4) }' || {
  echo "lid_up (lip up) support ${sup[lid_up]:-none} mm is not under a quarter of lip-down's ${sup[lid_down]:-none} mm"; fail=1; }
exit $fail
