#!/usr/bin/env bash
# bench_orient.sh BUILD - 1000-sample orientation of every shared mesh:
# wall time and candidates per second, side by side with Tweaker-3 (Cura's
# auto-orientation), and PrusaSlicer support grams for the input, our result
# and Tweaker's result (../shared/peers/slice-peers.sh, supports on, 45 deg).
#
# Tweaker-3 is not part of slimfarm: point TWEAKER_DIR at a checkout of it
# (MeshTweaker.py, Tweaker.py, FileHandler.py, ThreeMF.py; it runs with
# Debian's python3-numpy); without it that column is skipped.
# ORIENT_MESHES="anchor dino" limits the meshes, ORIENT_RUNS=N the timed runs
# (default 5, alternating ours and Tweaker's so load changes hit both), and
# ORIENT_GRAMS=0 skips the slicer peers (speed only).  ORIENT_BASE=DIR (a
# build tree with bin/ and libexec/, e.g. a copy of main's) is timed in the
# same alternation, so a change's before and after share the load; its
# column is base_s and base/ours.
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
# One timed run: "wall_s cpu_s" (wall from bash's microsecond clock, cpu =
# user + sys from GNU time, whose own wall figure has only 10 ms steps).
timed() {
  local t0=$EPOCHREALTIME t1
  /usr/bin/time -f '%U %S' -o "$work/time.1" "$@" >/dev/null 2>&1 || return 1
  t1=$EPOCHREALTIME
  awk -v w="$(echo "$t1 - $t0" | bc -l)" '{printf "%.4f %.2f\n", w, $1 + $2}' "$work/time.1"
}
median() { sort -n | awk '{a[NR] = $1} END {print NR % 2 ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
runs=${ORIENT_RUNS:-5}
base=${ORIENT_BASE:-}
[ -n "$base" ] && [ ! -x "$base/bin/slimfarm" ] && { echo "bench_orient: no $base/bin/slimfarm"; exit 1; }
echo "load average at start: $(cut -d' ' -f1-3 /proc/loadavg); $runs runs each, ours${base:+, base ($base)} and Tweaker-3 alternating; median wall s (median CPU s)"
printf '%-17s %14s %8s %14s %7s %7s %s %7s %7s %8s %s %7s %7s %8s%s\n' mesh ours_s cand/s tweaker_s \
  speed cpu '|' PS_in PS_ours PS_tweak '|' CE_in CE_ours CE_tweak "${base:+ | base_s base/ours tweaker/base}"
for f in "$(cd "$shared" && pwd)"/meshes/*.stl; do
  name=$(basename "$f" .stl)
  [ -n "${ORIENT_MESHES:-}" ] && [[ " $ORIENT_MESHES " != *" $name "* ]] && continue
  "$build/bin/slimfarm" orient "$f" -o "$work/$name-ours.stl" --samples 1000 --json > "$work/$name.json" || continue
  cands=$(/usr/bin/python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["candidates"])' "$work/$name.json")
  : > "$work/ours.t"; : > "$work/tw.t"; : > "$work/base.t"
  for ((r = 0; r < runs; r++)); do
    timed "$build/bin/slimfarm" orient "$f" -o "$work/$name-ours.stl" --samples 1000 >> "$work/ours.t"
    [ -n "$base" ] && timed "$base/bin/slimfarm" orient "$f" -o "$work/$name-base.stl" --samples 1000 >> "$work/base.t"
    [ -n "$tweaker" ] && (cd "$tweaker" && timed /usr/bin/python3 Tweaker.py -i "$f" -x -o "$work/$name-tweaker.stl") >> "$work/tw.t"
  done
  ours_s=$(cut -d' ' -f1 "$work/ours.t" | median) ours_c=$(cut -d' ' -f2 "$work/ours.t" | median)
  tw="-" tw_s=0 speed="-" cpu="-" tw_g="-" tw_ce="-"
  if [ -n "$tweaker" ] && [ -s "$work/tw.t" ]; then
    tw_s=$(cut -d' ' -f1 "$work/tw.t" | median) tw_c=$(cut -d' ' -f2 "$work/tw.t" | median)
    tw=$(printf '%.3f (%.2f)' "$tw_s" "$tw_c")
    speed=$(awk -v a="$tw_s" -v b="$ours_s" 'BEGIN {printf "%.1fx", a / b}')
    cpu=$(awk -v a="$tw_c" -v b="$ours_c" 'BEGIN {if (b > 0) printf "%.1fx", a / b; else print "-"}')
  fi
  if [ "${ORIENT_GRAMS:-1}" = 1 ]; then
    in_g=$(grams "$f") ours_g=$(grams "$work/$name-ours.stl")
    in_ce=$(grams "$f" curaengine) ours_ce=$(grams "$work/$name-ours.stl" curaengine)
    if [ -f "$work/$name-tweaker.stl" ]; then
      tw_g=$(grams "$work/$name-tweaker.stl") tw_ce=$(grams "$work/$name-tweaker.stl" curaengine)
    fi
  else
    in_g="-" ours_g="-" in_ce="-" ours_ce="-"
  fi
  base_col=""
  if [ -n "$base" ]; then
    base_s=$(cut -d' ' -f1 "$work/base.t" | median)
    base_col=$(awk -v b="$base_s" -v o="$ours_s" -v t="${tw_s:-0}" \
      'BEGIN {printf " | %6.3f %9.2fx %11s", b, b / o, (t > 0 ? sprintf("%.1fx", t / b) : "-")}')
  fi
  printf '%-17s %14s %8.0f %14s %7s %7s | %7s %7s %8s | %7s %7s %8s%s\n' "$name" \
    "$(printf '%.3f (%.2f)' "$ours_s" "$ours_c")" "$(awk -v c="$cands" -v s="$ours_s" 'BEGIN {print c / s}')" \
    "$tw" "$speed" "$cpu" "$in_g" "$ours_g" "$tw_g" "$in_ce" "$ours_ce" "$tw_ce" "$base_col"
done
echo "load average at end: $(cut -d' ' -f1-3 /proc/loadavg)"
