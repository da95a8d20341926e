#!/usr/bin/env bash
# tests/bench/gcode_digest.sh BUILD_DIR [OUT] - the SHA-256 of every G-code
# file the farm makes from the generated parts and the shared meshes: each
# part sliced as given, oriented, slimmed (volumetric) and reshaped
# (surface), then sliced.  A refactor that must not change behaviour keeps
# this list byte for byte: run it before and after and diff the two.
# The shared meshes ($SLIMFARM_SHARED/meshes, default ../shared) are skipped
# cleanly when absent; on them only the fast steps run (as given, oriented:
# half a minute on 2 cores) unless FULL=1 (all four steps: many minutes).  Prints "sha256  part.step" lines (to OUT if given).
set -euo pipefail
build=${1:?usage: tests/bench/gcode_digest.sh BUILD_DIR [OUT]}
out=${2:-/dev/stdout}
sf="$build/bin/slimfarm"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$sf" shapes "$work/parts" > /dev/null
meshes=${SLIMFARM_SHARED:-../shared}/meshes
digest() { # NAME MESH
  "$sf" slice "$2" -o "$work/$1.gcode" > /dev/null
  (cd "$work" && sha256sum "$1.gcode")
}
{
  for p in "$work"/parts/*.stl; do
    n=$(basename "$p" .stl)
    digest "$n.given" "$p"
    "$sf" orient "$p" -o "$work/$n.orient.stl" > /dev/null && digest "$n.orient" "$work/$n.orient.stl"
    "$sf" optimize "$p" -o "$work/$n.slim.stl" --method volumetric > /dev/null &&
      digest "$n.slim" "$work/$n.slim.stl"
    "$sf" optimize "$p" -o "$work/$n.surface.stl" --method surface > /dev/null &&
      digest "$n.surface" "$work/$n.surface.stl"
  done
  if [ -d "$meshes" ]; then
    for p in "$meshes"/*.stl; do
      n=$(basename "$p" .stl)
      digest "$n.given" "$p"
      "$sf" orient "$p" -o "$work/$n.orient.stl" > /dev/null && digest "$n.orient" "$work/$n.orient.stl"
      [ "${FULL:-0}" = 1 ] || continue
      "$sf" optimize "$p" -o "$work/$n.slim.stl" --method volumetric > /dev/null &&
        digest "$n.slim" "$work/$n.slim.stl"
      "$sf" optimize "$p" -o "$work/$n.surface.stl" --method surface > /dev/null &&
        digest "$n.surface" "$work/$n.surface.stl"
    done
  else
    echo "# ../shared/meshes absent: generated parts only" >&2
  fi
} > "$out"
