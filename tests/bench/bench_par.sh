#!/usr/bin/env bash
# bench_par.sh BUILD - the compute runtime (src/base/par.c, issue 15).
#
# 1. Wall and CPU seconds of `slimfarm orient`, `optimize --method
#    volumetric`, `optimize --method surface` and `slice` on three shared
#    meshes: this build with its default budget (every core), the same with
#    SLIMFARM_THREADS=1, and PAR_BASE (a build tree with bin/ and libexec/,
#    e.g. a copy of main's) if given, run in alternation so that the load of
#    a shared machine hits all three alike; median of PAR_RUNS runs.  The
#    "same" column says whether this build's output (oriented STL, optimized
#    STL, G-code) is byte-identical to the base's, and to its own
#    one-thread run.
# 2. The daemon's prepare throughput: slimfarmd (its prepare pool has one
#    worker per core, par_share divides the cores between them) gets two
#    jobs at once (--method orient, then slim) and the seconds from the
#    first submit until both are ready are timed, ours and base alternating.
#
# PAR_MESHES (default "anchor elephant armadillo"), PAR_RUNS (3),
# PAR_CMDS (default "orient volumetric surface slice"), PAR_CMDS=none or
# PAR_DAEMON=0 skips part 1 or 2, PAR_METHODS (default "orient slim"),
# PAR_DAEMON_MESH (dino).
# Figures only: it never fails on time.
set -u
umask 077 # slimfarmd refuses a farm.ini holding keys that others can read
build=${1:-build/rel}
shared=${SLIMFARM_SHARED:-../shared}
[ -d "$shared/meshes" ] || { echo "bench_par: $shared/meshes absent, skipped"; exit 0; }
shared=$(cd "$shared" && pwd)
base=${PAR_BASE:-}
[ -n "$base" ] && [ ! -x "$base/bin/slimfarm" ] && { echo "bench_par: no $base/bin/slimfarm"; exit 1; }
[ -x "$build/bin/slimfarm" ] || { echo "bench_par: $build not built"; exit 1; }
runs=${PAR_RUNS:-3}
work=$(mktemp -d)
dpid=
cleanup() { [ -n "$dpid" ] && kill "$dpid" 2>/dev/null; wait 2>/dev/null; rm -rf "$work"; }
trap cleanup EXIT

# timed TAG CMD...: one run; appends "wall_s cpu_s" to $work/TAG.t (wall from
# bash's microsecond clock, cpu = user + sys of the process tree from GNU time)
timed() {
  local tag=$1 t0=$EPOCHREALTIME t1; shift
  /usr/bin/time -f '%U %S' -o "$work/time.1" "$@" > /dev/null 2>&1 || { echo "fail fail" >> "$work/$tag.t"; return 1; }
  t1=$EPOCHREALTIME
  awk -v a="$t0" -v b="$t1" '{ printf "%.3f %.2f\n", b - a, $1 + $2 }' "$work/time.1" >> "$work/$tag.t"
}
median() { sort -n | awk '{ a[NR] = $1 } END { if (!NR) print "-"; else print NR % 2 ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2 }'; }
col() { cut -d' ' -f"$2" "$work/$1.t" | median; }
# argv VARIANT CMD MESH OUT: the command line of one variant, into $A
argv() {
  local v=$1 cmd=$2 mesh=$3 out=$4 bin=$build/bin/slimfarm
  [ "$v" = base ] && bin=$base/bin/slimfarm
  A=(env)
  [ "$v" = one ] && A+=(SLIMFARM_THREADS=1)
  case $cmd in
  orient) A+=("$bin" orient "$mesh" -o "$out.stl") ;;
  volumetric | surface) A+=("$bin" optimize "$mesh" -o "$out.stl" --method "$cmd") ;;
  slice) A+=("$bin" slice "$mesh" -o "$out.gcode") ;;
  esac
}
variants="ours one"
[ -n "$base" ] && variants="base ours one"

echo "bench_par: $(nproc) cores; load average at start $(cut -d' ' -f1-3 /proc/loadavg); $runs runs each, ${variants// /, } alternating"
echo "median wall s (median CPU s); ours = default budget (every core), one = SLIMFARM_THREADS=1"
printf '%-10s %-10s %15s %15s %15s %9s %9s %s\n' mesh command base ours one ours/base one/ours same
[ "${PAR_CMDS:-}" = none ] && PAR_MESHES=" "
for name in ${PAR_MESHES:-anchor elephant armadillo}; do
  mesh=$shared/meshes/$name.stl
  [ -f "$mesh" ] || { echo "bench_par: no $mesh"; continue; }
  for cmd in ${PAR_CMDS:-orient volumetric surface slice}; do
    for v in $variants; do : > "$work/$v.t"; done
    for ((r = 0; r < runs; r++)); do
      for v in $variants; do
        argv "$v" "$cmd" "$mesh" "$work/$v-$cmd"
        timed "$v" "${A[@]}"
      done
    done
    ext=stl; [ "$cmd" = slice ] && ext=gcode
    same="one:$(cmp -s "$work/ours-$cmd.$ext" "$work/one-$cmd.$ext" && echo yes || echo NO)"
    [ -n "$base" ] && same="base:$(cmp -s "$work/ours-$cmd.$ext" "$work/base-$cmd.$ext" && echo yes || echo NO) $same"
    cell() { [ -s "$work/$1.t" ] && printf '%.3f (%.2f)' "$(col "$1" 1)" "$(col "$1" 2)" || echo -; }
    b="-"; rb="-"
    if [ -n "$base" ]; then
      b=$(cell base)
      rb=$(awk -v o="$(col ours 1)" -v b="$(col base 1)" 'BEGIN { printf "%.2f", o / b }')
    fi
    ro=$(awk -v o="$(col ours 1)" -v s="$(col one 1)" 'BEGIN { printf "%.2f", s / o }')
    printf '%-10s %-10s %15s %15s %15s %9s %9s %s\n' "$name" "$cmd" "$b" "$(cell ours)" "$(cell one)" "$rb" "$ro" "$same"
  done
done
echo "load average after part 1: $(cut -d' ' -f1-3 /proc/loadavg)"

[ "${PAR_DAEMON:-1}" = 0 ] && exit 0
# ---- part 2: two jobs at once through slimfarmd's prepare pool ----
dmesh=$shared/meshes/${PAR_DAEMON_MESH:-dino}.stl
key=bench-key-0123456789abcdef
cp -r config/printers config/materials "$work/" 2>/dev/null ||
  { echo "bench_par: run from the repository root (config/)"; exit 0; }
# prepare_pair TREE METHOD: start a daemon from TREE, submit two jobs at
# once, print the seconds until both are ready and the daemon's CPU
# seconds (user + sys) by then (or "fail")
prepare_pair() {
  local tree=$1 method=$2 port=$((20000 + RANDOM % 20000)) d=$work/d.$RANDOM
  mkdir -p "$d"
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n[printer mk3]\ndriver: marlin\nport: pty:/dev/null\nmaterial: PLA\n' \
    "$port" "$d" "$key" > "$work/farm.ini"
  (cd "$work" && exec "$tree/bin/slimfarmd" -c "$work/farm.ini") > "$d/log" 2>&1 &
  dpid=$!
  local c="$tree/bin/slimfarm"
  export SLIMFARM_URL=http://127.0.0.1:$port SLIMFARM_API_KEY=$key
  for _ in $(seq 200); do "$c" jobs > /dev/null 2>&1 && break; sleep 0.05; done
  local t0=$EPOCHREALTIME ok=0
  "$c" submit "$dmesh" --method "$method" > /dev/null && "$c" submit "$dmesh" --method "$method" > /dev/null ||
    { echo fail; kill "$dpid"; wait "$dpid" 2>/dev/null; dpid=; return; }
  for _ in $(seq 6000); do
    "$c" jobs > "$d/jobs" 2>/dev/null
    [ "$(grep -cE '^[0-9]+ +ready' "$d/jobs")" = 2 ] && { ok=1; break; }
    grep -qE '^[0-9]+ +failed' "$d/jobs" && break
    sleep 0.05
  done
  local t1=$EPOCHREALTIME
  local cpu; cpu=$(awk -v hz="$(getconf CLK_TCK)" '{ sub(/.*\) /, ""); printf "%.2f", ($12 + $13) / hz }' "/proc/$dpid/stat")
  kill "$dpid"; wait "$dpid" 2>/dev/null; dpid=
  [ "$ok" = 1 ] && awk -v a="$t0" -v b="$t1" -v c="$cpu" 'BEGIN { printf "%.2f %s\n", b - a, c }' || echo fail
}
trees="$build"
[ -n "$base" ] && trees="$base $build"
echo "daemon: two jobs submitted at once ($(basename "$dmesh")), seconds until both are ready (polled every 0.05 s) (daemon CPU s), median of $runs, alternating; load $(cut -d' ' -f1-3 /proc/loadavg)"
printf '%-8s %15s %15s %s\n' method base ours "wall s of each run, base / ours"
for method in ${PAR_METHODS:-orient slim}; do
  : > "$work/pb"; : > "$work/po"
  for ((r = 0; r < runs; r++)); do
    [ -n "$base" ] && prepare_pair "$(cd "$base" && pwd)" "$method" >> "$work/pb"
    prepare_pair "$(cd "$build" && pwd)" "$method" >> "$work/po"
  done
  med() { grep -v fail "$1" | cut -d' ' -f"$2" | median; }
  cellp() { [ -s "$1" ] && printf '%s (%s)' "$(med "$1" 1)" "$(med "$1" 2)" || echo -; }
  printf '%-8s %15s %15s %s / %s\n' "$method" "$(cellp "$work/pb")" "$(cellp "$work/po")" \
    "$(cut -d' ' -f1 "$work/pb" | tr '\n' ' ')" "$(cut -d' ' -f1 "$work/po" | tr '\n' ' ')"
done
echo "load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)"
