#!/usr/bin/env bash
# bench_slice.sh BUILD - our slicer against PrusaSlicer 2.5 (shared/peers)
# on the shared meshes, supports off and on, same settings (0.2 mm, 2
# perimeters, 4/3 solid, 15 % grid, 0.45 mm lines, PrusaSlicer's stock
# speeds and machine limits, which are our defaults).  Prints one table
# row per mesh: filament (g) and estimated time (min) of both slicers with
# the ratio, support grams, and slicing wall time (best of 3 for ours, one
# run for PrusaSlicer, startup included in both), and our planner's
# estimate of PrusaSlicer's own G-code ("planner" column: it isolates the
# estimator from the differences between the two slicers' toolpaths).
# CuraEngine's filament, estimate and wall time (its stock 0.4 mm lines
# and speeds, so a second opinion, not a like-for-like) close each row.
# CPU seconds (user + system, from GNU time: the machine is shared, so wall
# time says more about the load than about the slicer) are taken side by
# side: ours and CuraEngine alternate, three runs each, best of each; the
# "CPU ratio" column is ours / CuraEngine's, "wall ratio vs CE" the same
# for the best wall times of those runs.  The last column counts our
# move commands (G1/G2/G3) with arcs and with arc_fitting = no.
# Both slicers' time estimates are with cooling on (PrusaSlicer's default
# cooling = 1 and our material defaults: slowdown below 5 s, fan by layer
# time), so "time ratio" compares what each would print, minimum layer
# time included.  BENCH_RUNS (default 3) sets the alternations;
# BENCH_CE_ROW=0 skips CuraEngine's own filament/estimate row (one more
# niced run per mesh; the CPU columns still come from the side-by-side runs).
# BENCH_SET picks the sets (tests/bench/valsets.sh): shared (default), mech,
# scad, or several ("mech scad", all); each set gets its table and a total
# row per support setting (sums over the parts both slicers sliced; the
# ratios of the sums).
# BENCH_MESHES="a.stl b.stl" picks meshes instead (one set, "given");
# BENCH_PEERS=0 skips the peers;
# BENCH_SUPPORT="off" runs only supports off (default "off on"); BENCH_PS=0
# leaves PrusaSlicer out (CuraEngine's CPU ratio only).
# Each set's second table reads both G-codes by ;TYPE: role
# (tests/bench/valsets/gcstats.py): filament mm per role, ours / PrusaSlicer
# (perimeters, external and overhang perimeters, sparse infill, solid and top
# solid infill, gap fill, bridge infill, support, support interface), and
# the strength check: perimeter loops per contour and the solid skin over
# and under sparse infill (median, mm); a row where ours has fewer loops
# (by more than 0.02) or a thinner top or bottom than PrusaSlicer's is
# flagged WEAKER.
set -u
build=${1:-build/rel}
shared=${SLIMFARM_SHARED:-../shared}
bin="$build/bin/slimfarm"
[ -x "$bin" ] || { echo "bench_slice: $bin not built"; exit 1; }
if [ -n "${BENCH_MESHES:-}" ]; then list=$(printf 'given\t%s\n' $BENCH_MESHES)
else
  # shellcheck disable=SC2086
  list=$("$(dirname "$0")/valsets.sh" ${BENCH_SET:-shared})
fi
[ -n "$list" ] || { echo "bench_slice: no meshes in set ${BENCH_SET:-shared}, nothing to compare"; exit 0; }
gcstats="python3 $(dirname "$0")/valsets/gcstats.py"
peers=${BENCH_PEERS:-1}
if [ "$peers" = 1 ] && ! command -v prusa-slicer >/dev/null; then
  echo "bench_slice: prusa-slicer missing (make bench installs it); ours only"; peers=0
fi
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
# GNU time on PATH for the peers' script, keeping a copy of its report
mkdir -p "$work/tbin"
cat > "$work/tbin/time" <<'EOF2'
#!/usr/bin/env bash
out=""; a=("$@")
for ((i = 0; i < ${#a[@]}; i++)); do [ "${a[i]}" = -o ] && { out=${a[i + 1]}; break; }; done  # time's own -o
/usr/bin/time "$@"; rc=$?
[ -n "$out" ] && [ -n "${BENCH_TIME_COPY:-}" ] && cp "$out" "$BENCH_TIME_COPY"
exit $rc
EOF2
chmod +x "$work/tbin/time"

# ours, once: "wall_s cpu_s", and the figures printed by `slimfarm slice` in $work/o.line
ours_run() { # mesh support(on|off)
  local flag=""
  [ "$2" = off ] && flag=--no-support
  # like the peers: no skirt, no brim (slice-peers.sh passes --skirts 0 --brim-width 0)
  flag="$flag --set skirts=0 --set brim_auto=no"
  rm -f "$work/o.gcode" # a failed slice leaves no G-code to read
  /usr/bin/time -f "%e %U %S" -o "$work/o.time" "$bin" slice "$1" -o "$work/o.gcode" $flag \
    >"$work/o.line" 2>/dev/null || { echo "0 0"; return; }
  awk '{ printf "%s %.2f\n", $1, $2 + $3 }' "$work/o.time"
}
# CuraEngine once through the peers' script: "wall_s cpu_s"
ce_run() { # mesh support
  rm -f "$work/ce.time"
  PATH="$work/tbin:$PATH" BENCH_TIME_COPY="$work/ce.time" PEER_RUNS="curaengine:$2" \
    bash "$shared/peers/slice-peers.sh" "$1" --format csv >/dev/null 2>&1
  awk -F': ' '/Elapsed \(wall clock\)/ { n = split($2, t, ":"); w = 0; for (i = 1; i <= n; i++) w = w * 60 + t[i] }
    /User time/ { u = $2 } /System time/ { s = $2 } END { printf "%.2f %.2f\n", w, u + s }' "$work/ce.time" 2>/dev/null
}
# ours and CuraEngine alternating, three runs each: "g min support_g wall_s layers cpu_s ce_cpu_s ce_wall_s"
ours() { # mesh support(on|off)
  local best=999999 cpu=999999 ccpu=999999 cwall=999999 w c
  for ((run = 0; run < ${BENCH_RUNS:-3}; run++)); do
    read -r w c <<<"$(ours_run "$1" "$2")"
    [ "$c" = 0 ] && { echo "0 0 0 0 0 0 0 0"; return; }
    best=$(awk -v a="$best" -v b="$w" 'BEGIN { print (b < a ? b : a) }')
    cpu=$(awk -v a="$cpu" -v b="$c" 'BEGIN { print (b < a ? b : a) }')
    cp "$work/o.line" "$work/o.keep"
    if [ "$peers" = 1 ] && command -v CuraEngine >/dev/null; then
      read -r w c <<<"$(ce_run "$1" "$2")"
      [ -n "$c" ] && ccpu=$(awk -v a="$ccpu" -v b="$c" 'BEGIN { print (b < a ? b : a) }')
      [ -n "$w" ] && cwall=$(awk -v a="$cwall" -v b="$w" 'BEGIN { print (b < a ? b : a) }')
    fi
  done
  [ "$ccpu" = 999999 ] && ccpu=0 cwall=0
  local g sg layers secs line
  line=$(cat "$work/o.keep")
  g=$(sed -n 's/.*filament [0-9]* mm \([0-9.]*\) g.*/\1/p' <<<"$line")
  sg=$(sed -n 's/.*(support \([0-9.]*\) g).*/\1/p' <<<"$line")
  layers=$(sed -n 's/.*: \([0-9]*\) layers.*/\1/p' <<<"$line")
  secs=$(sed -n 's/^; estimated printing time \[s\] = //p' "$work/o.gcode")
  # move commands with arcs (this file) and without (arc_fitting = no)
  local mv_arc mv_lin flag=""
  mv_arc=$(grep -c '^G[123] ' "$work/o.gcode")
  [ "$2" = off ] && flag=--no-support
  "$bin" slice "$1" -o "$work/l.gcode" $flag --set skirts=0 --set brim_auto=no \
    --set arc_fitting=no >/dev/null 2>&1 && mv_lin=$(grep -c '^G[123] ' "$work/l.gcode")
  echo "$g $(awk -v s="$secs" 'BEGIN { printf "%.1f", s / 60 }') $sg $best $layers $cpu $ccpu $cwall $mv_arc ${mv_lin:-0}"
}
# A peer's row and its G-code (gzip) are cached by the mesh's content under
# $PEER_CACHE/slice (default build/peercache): written to a temporary name,
# then moved into place, so trees sharing a cache never read half a file.
# The planner column is always our estimator run on the cached G-code.
cache=${PEER_CACHE:-build/peercache}/slice
peer() { # mesh support [slicer] -> "g min support_g wall_s layers planner_min"
  local row est key slicer=${3:-prusaslicer}
  key="$cache/$(md5sum <"$1" | cut -c1-32).$slicer.$2"
  rm -rf "$work/peer"; mkdir -p "$work/peer" "$cache"
  if [ -s "$key.csv" ] && [ -s "$key.gcode.gz" ]; then
    row=$(tail -n 1 "$key.csv"); gzip -dc "$key.gcode.gz" >"$work/peer/peer.gcode"
  else
    row=$(PEER_RUNS="$slicer:$2" nice -n 19 bash "$shared/peers/slice-peers.sh" "$1" --format csv --keep "$work/peer" 2>/dev/null | tail -n 1)
    if [ "$(cut -d, -f8 <<<"$row")" = 0 ] && ls "$work"/peer/*.gcode >/dev/null 2>&1; then
      gzip -c "$work"/peer/*.gcode >"$key.gcode.gz.$$" && mv "$key.gcode.gz.$$" "$key.gcode.gz"
      echo "$row" >"$key.csv.$$" && mv "$key.csv.$$" "$key.csv"
    fi
  fi
  est=$("$bin" estimate "$work"/peer/*.gcode 2>/dev/null | sed -n 's/.*(\([0-9]*\) s)$/\1/p')
  python3 - "$row" "${est:-0}" <<'PY'
import sys, csv
r = next(csv.reader([sys.argv[1]]))
try:
    h = "mesh,triangles,manifold,slicer,version,support,angle_deg,rc,wall_s,max_rss_mb,filament_mm,filament_g,support_mm,support_g,est_time_s,layers,slicer_filament_mm".split(",")
    d = dict(zip(h, r))
    print(d["filament_g"], "%.1f" % (float(d["est_time_s"]) / 60), d["support_g"], d["wall_s"], d["layers"],
          "%.1f" % (float(sys.argv[2]) / 60))
except Exception:
    print("0 0 0 0 0 0")
PY
}
table_head() {
  printf '| mesh | support | ours g | PS g | g ratio | ours min | PS min | time ratio | planner on PS G-code min | ours support g | PS support g | ours wall s | PS wall s | wall ratio | CE g | CE min | CE wall s | ours CPU s | CE CPU s | CPU ratio vs CE | wall ratio vs CE | moves, arcs / no arcs |\n'
  printf '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n'
}
# set_end SET: the set's total rows, then its per-role table
set_end() {
  # over the parts both slicers sliced (a failed slice prints zeros)
  awk -F'\t' -v set="$1" 'function r(a, b) { return b > 0 ? sprintf("%.2f", a / b) : "-" }
    { all[$2]++ } $3 > 0 && $4 > 0 { og[$2] += $3; pg[$2] += $4; om[$2] += $5; pm[$2] += $6; os[$2] += $7; ps[$2] += $8
      cg[$2] += $9; cm[$2] += $10; n[$2]++ }
    END { for (s in all) printf "| **total %s (%d of %d parts)** | %s | %.2f | %.2f | %s | %.1f | %.1f | %s | | %.2f | %.2f | | | | %.2f | %.1f | | | | | | |\n",
            set, n[s], all[s], s, og[s], pg[s], r(og[s], pg[s]), om[s], pm[s], r(om[s], pm[s]), os[s], ps[s], cg[s], cm[s] }' "$work/sums"
  echo
  echo "filament mm by ;TYPE: role, ours / PrusaSlicer; walls = perimeter loops per contour; top, bottom = solid skin over / under sparse infill (median mm)"
  echo
  printf '| mesh | support | perimeter | external + overhang | internal infill | solid + top solid | gap fill | bridge | support | support interface | walls | top mm | bottom mm | strength |\n'
  printf '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n'
  cat "$work/roles"
  echo
  : >"$work/sums"; : >"$work/roles"
}
# roles MESH SUPPORT OURS_GCODE PS_GCODE: one row of the per-role table
roles() {
  local o p
  o=$([ -s "$3" ] && $gcstats "$3" 2>/dev/null)
  p=$([ -s "$4" ] && $gcstats "$4" 2>/dev/null)
  awk -v m="$(basename "$1")" -v s="$2" -v o="$o" -v p="$p" 'function kv(line, a,   i, f, kw) {
      split(line, f, " "); for (i in f) { split(f[i], kw, "="); a[kw[1]] = kw[2] } }
    function pair(k) { return (k in A ? A[k] : "-") " / " (k in B ? B[k] : "-") }
    function less(k, tol) { return (k in A) && (k in B) && A[k] != "-" && B[k] != "-" && A[k] + tol < B[k] + 0 }
    BEGIN { kv(o, A); kv(p, B); weak = ""
      if (less("walls", 0.02)) weak = weak " walls"
      if (less("top", 0.001)) weak = weak " top"
      if (less("bottom", 0.001)) weak = weak " bottom"
      printf "| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |\n", m, s, pair("perim"), pair("ext"),
        pair("infill"), pair("solid"), pair("gap"), pair("bridge"), pair("support"), pair("iface"), pair("walls"),
        pair("top"), pair("bottom"), o == "" ? "**ours failed**" : p == "" ? "no PS G-code" : weak == "" ? "ok" : "**WEAKER:" weak "**" }'
}
: >"$work/sums"; : >"$work/roles"
prev_set=
while IFS=$'\t' read -r set m; do
  if [ "$set" != "$prev_set" ]; then
    [ -n "$prev_set" ] && set_end "$prev_set"
    echo "== set $set"; echo; table_head; prev_set=$set
  fi
  for sup in ${BENCH_SUPPORT:-off on}; do
    read -r og omin osg ow ol ocpu ccpu ccw marc mlin <<<"$(ours "$m" "$sup")"
    if [ "$peers" = 1 ] && [ "${BENCH_PS:-1}" = 1 ]; then read -r pg pmin psg pw pl pest <<<"$(peer "$m" "$sup")"
    else pg=0 pmin=0 psg=0 pw=0 pest=0; rm -rf "$work/peer"; fi
    roles "$m" "$sup" "$work/o.gcode" "$(ls "$work"/peer/*.gcode 2>/dev/null | head -n 1)" >>"$work/roles"
    if [ "$peers" = 1 ] && [ "${BENCH_CE_ROW:-1}" = 1 ] && command -v CuraEngine >/dev/null; then
      read -r cg cmin csg cw cl cest <<<"$(peer "$m" "$sup" curaengine)"
    else cg=0 cmin=0 cw=0; fi
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$(basename "$m")" "$sup" "$og" "$pg" "$omin" "$pmin" "$osg" "$psg" "$cg" "$cmin" >>"$work/sums"
    awk -v m="$(basename "$m")" -v s="$sup" -v og="$og" -v pg="$pg" -v omin="$omin" -v pmin="$pmin" \
        -v osg="$osg" -v psg="$psg" -v ow="$ow" -v pw="$pw" -v pest="$pest" \
        -v cg="$cg" -v cmin="$cmin" -v cw="$cw" -v oc="$ocpu" -v cc="$ccpu" -v ccw="$ccw" -v ma="$marc" -v ml="$mlin" 'function r(a, b) { return b > 0 ? sprintf("%.2f", a / b) : "-" }
      BEGIN { printf "| %s | %s | %.2f | %.2f | %s | %.1f | %.1f | %s | %.1f (%s) | %.2f | %.2f | %.2f | %.2f | %s | %.2f | %.1f | %.2f | %.2f | %.2f | %s | %s | %d / %d (%sx fewer) |\n",
              m, s, og, pg, r(og, pg), omin, pmin, r(omin, pmin), pest, r(pest, pmin), osg, psg, ow, pw, r(ow, pw),
              cg, cmin, cw, oc, cc, r(oc, cc), r(ow, ccw), ma, ml, r(ml, ma) }'
  done
done <<<"$list"
[ -n "$prev_set" ] && set_end "$prev_set"
