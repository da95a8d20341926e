#!/usr/bin/env bash
# bench_orient.sh BUILD - 1000-sample orientation of every shared mesh:
# wall time and candidates per second, side by side with Tweaker-3 (Cura's
# auto-orientation), and PrusaSlicer support grams for the input, our result
# and Tweaker's result (../shared/peers/slice-peers.sh, supports on, 45 deg).
#
# Tweaker-3 is not part of slimfarm: point TWEAKER_DIR at a checkout of it
# (MeshTweaker.py, Tweaker.py, FileHandler.py, ThreeMF.py; it runs with
# Debian's python3-numpy); without it that column is skipped.
# ORIENT_MESHES="anchor dino" limits the meshes.
set -u
build=${1:-build/rel}
shared=${SLIMFARM_SHARED:-../shared}
[ -d "$shared/meshes" ] || { echo "bench_orient: $shared/meshes absent, skipped"; exit 0; }
peers="$shared/peers/slice-peers.sh"
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
tweaker=${TWEAKER_DIR:-}
[ -n "$tweaker" ] && [ ! -f "$tweaker/Tweaker.py" ] && tweaker=""
grams() { # mesh [slicer] -> support grams (PrusaSlicer by default)
  PEER_RUNS=${2:-prusaslicer}:on "$peers" "$1" --format csv 2>/dev/null | awk -F, 'NR==2 {print $14}'
}
now() { date +%s.%N; }
printf '%-22s %8s %9s %8s %9s | %8s %8s %8s | %8s %8s %8s\n' mesh ours_s cand/s tweak_s \
  speedup PS_in_g PS_ours PS_tweak CE_in_g CE_ours CE_tweak
for f in "$(cd "$shared" && pwd)"/meshes/*.stl; do
  name=$(basename "$f" .stl)
  [ -n "${ORIENT_MESHES:-}" ] && [[ " $ORIENT_MESHES " != *" $name "* ]] && continue
  t0=$(now)
  "$build/bin/slimfarm" orient "$f" -o "$work/$name-ours.stl" --samples 1000 --json > "$work/$name.json" || continue
  t1=$(now)
  cands=$(/usr/bin/python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["candidates"])' "$work/$name.json")
  ours_s=$(echo "$t1 - $t0" | bc -l)
  tw_s="-" tw_g="-" tw_ce="-" speed="-"
  if [ -n "$tweaker" ]; then
    t2=$(now)
    (cd "$tweaker" && /usr/bin/python3 Tweaker.py -i "$f" -x -o "$work/$name-tweaker.stl" >/dev/null 2>&1)
    t3=$(now)
    tw_s=$(printf '%.2f' "$(echo "$t3 - $t2" | bc -l)")
    speed=$(printf '%.1fx' "$(echo "($t3 - $t2) / $ours_s" | bc -l)")
    if [ -f "$work/$name-tweaker.stl" ]; then
      tw_g=$(grams "$work/$name-tweaker.stl")
      tw_ce=$(grams "$work/$name-tweaker.stl" curaengine)
    fi
  fi
  printf '%-22s %8.2f %9.0f %8s %9s | %8s %8s %8s | %8s %8s %8s\n' "$name" "$ours_s" \
    "$(echo "$cands / $ours_s" | bc -l)" "$tw_s" "$speed" "$(grams "$f")" \
    "$(grams "$work/$name-ours.stl")" "$tw_g" "$(grams "$f" curaengine)" \
    "$(grams "$work/$name-ours.stl" curaengine)" "$tw_ce"
done
