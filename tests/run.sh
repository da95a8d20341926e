#!/usr/bin/env bash
# tests/run.sh BUILD_DIR [FILTER]
# Runs every unit test program in BUILD_DIR/tests, the libFuzzer smoke runs
# and the integration tests (those whose names contain FILTER, or one of its
# words: "test_farm store_pg"), JOBS at a time, and ends with the line CI reads:
#   total: N passed, N failed
# A program that crashes counts all its cases as failed.
#
# Side by side: every test works in a directory of its own (mktemp), and
# every daemon and simulator listens on a port the kernel picks
# (tests/integ/lib/daemon.sh), so no two tests share a path or a port.  The
# scenarios wait for states with generous bounds, never for a time, so a
# busy neighbour slows them.  JOBS (default: one per core) is how many run
# at once: the scenarios spend most of their time waiting for simulated
# printers, the unit tests computing.  Each test's output is printed whole
# when it ends, with its wall-clock and CPU time; the slowest are listed
# last.  JOBS=1 runs one at a time, in order.
set -u
# Files the tests write are their owner's alone, as slimfarmd wants of a
# config holding keys (it refuses one others can read).
umask 077
build=${1:?usage: tests/run.sh BUILD_DIR [FILTER]}
filter=${2:-}
jobs=${JOBS:-$(nproc)}
res=$(mktemp -d)
trap 'rm -rf "$res"' EXIT
t_all=$(date +%s%N)
# whether name $1 is one FILTER selects
selected() {
  local w
  [ -z "$filter" ] && return 0
  for w in $filter; do [[ "$1" == *"$w"* ]] && return 0; done
  return 1
}

# The body of each test runs in a subshell of its own, writing its output
# to $res/K.out and then its result, "PASS FAIL SKIP WALL_MS CPU_MS LABEL",
# to $res/K.res (LABEL: what failed, "-" if nothing did).  CPU_MS is the
# CPU time of the test's processes (bash's times in that subshell), which a
# loaded machine stretches far less than the wall clock.
result() { # K T0 PASS FAIL SKIP LABEL
  local ms=$((($(date +%s%N) - $2) / 1000000)) cpu
  times > "$res/$1.times"
  cpu=$(awk 'NR == 2 { n = 0; for (i = 1; i <= 2; i++) { split($i, a, /[ms]/); n += a[1] * 60 + a[2] }
                       printf "%d", n * 1000 }' "$res/$1.times")
  echo "$3 $4 $5 $ms $cpu $6" > "$res/$1.tmp" && mv "$res/$1.tmp" "$res/$1.res"
}

unit() { # K PROG NAME
  local t0 out rc last
  t0=$(date +%s%N)
  out=$(timeout 600 "$2" 2>&1); rc=$? # a hung program fails, never hangs the run
  printf '%s\n' "$out" | grep -v '^ok ' || true
  last=$(printf '%s\n' "$out" | tail -n 1)
  if [[ "$last" =~ ^([0-9]+)\ passed,\ ([0-9]+)\ failed,\ ([0-9]+)\ skipped$ ]]; then
    local p=${BASH_REMATCH[1]} f=${BASH_REMATCH[2]} s=${BASH_REMATCH[3]} label=-
    [ "$f" -ne 0 ] && label=$3
    [ "$rc" -ne 0 ] && [ "$f" -eq 0 ] && { f=1; label="$3(rc=$rc)"; }
    result "$1" "$t0" "$p" "$f" "$s" "$label"
  else
    local n
    n=$("$2" --count 2> /dev/null || echo 1)
    echo "   $3 crashed (rc=$rc): counting its $n cases as failed"
    result "$1" "$t0" 0 "$n" 0 "$3(crash)"
  fi
}

# libFuzzer smoke runs: a fixed number of mutations per parser (make fuzz runs long).
fuzz() { # K FUZZER NAME
  local t0 work dict=
  t0=$(date +%s%N)
  work=$(mktemp -d)
  cp -r "tests/fuzz/corpus/$3/." "$work/" 2> /dev/null
  [ -f "tests/fuzz/$3.dict" ] && dict="-dict=tests/fuzz/$3.dict"
  if "$2" -runs="${FUZZ_RUNS:-3000}" -max_len=65536 $dict "$work" > "$work.log" 2>&1; then
    echo "   $(grep -o 'Done [0-9]* runs' "$work.log" | head -1)"
    result "$1" "$t0" 1 0 0 -
  else
    echo "   FAILED"
    tail -40 "$work.log"
    result "$1" "$t0" 0 1 0 "fuzz_$3"
  fi
  rm -rf "$work" "$work.log"
}

integ() { # K SCRIPT NAME
  local t0
  t0=$(date +%s%N)
  # a hung scenario fails instead of hanging the run (CI has 90 minutes in all)
  if BUILD="$build" timeout 600 bash "$2" < /dev/null; then
    result "$1" "$t0" 1 0 0 -
  else
    result "$1" "$t0" 0 1 0 "integ/$3"
  fi
}

# The queue, longest first so the last to end is a short one: the browser
# test and the scenarios, the unit test programs, the fuzz runs.
queue=()
for script in tests/browser/*.sh tests/integ/*.sh; do
  [ -f "$script" ] || continue
  name=$(basename "$script" .sh)
  selected "$name" || continue
  queue+=("integ $script $name")
done
for prog in "$build"/tests/test_*; do
  [ -x "$prog" ] || continue
  name=$(basename "$prog")
  # only programs whose source still exists (a stale binary from another branch is no test)
  src=tests/unit/$name.c
  [[ $name == test_fuzz_* ]] && src=tests/fuzz/fuzz_${name#test_fuzz_}.c
  [ -f "$src" ] || continue
  selected "$name" || continue
  queue+=("unit $prog $name")
done
for fz in build/fuzz/fuzz_*; do
  [ -x "$fz" ] && [ -f "$fz" ] || continue
  name=$(basename "$fz")
  name=${name#fuzz_}
  [ -f "tests/fuzz/fuzz_$name.c" ] || continue
  selected "fuzz_$name" || continue
  queue+=("fuzz $fz $name")
done

pass=0 fail=0 skip=0 failed_progs=() took=() shown=()
# report: print every test that has ended and is not shown yet
report() {
  local k p f s ms cpu label kind name
  for ((k = 0; k < ${#queue[@]}; k++)); do
    [ -n "${shown[k]:-}" ] || [ ! -f "$res/$k.res" ] && continue
    shown[k]=1
    read -r kind _ name <<< "${queue[k]}"
    read -r p f s ms cpu label < "$res/$k.res"
    [ "$kind" = unit ] && echo "== $name" || echo "== $kind $name"
    cat "$res/$k.out"
    printf -- '-- %s: %d.%d s, cpu %d.%d s\n' "$name" $((ms / 1000)) $((ms % 1000 / 100)) \
      $((cpu / 1000)) $((cpu % 1000 / 100))
    pass=$((pass + p)) fail=$((fail + f)) skip=$((skip + s))
    [ "$label" != - ] && failed_progs+=("$label")
    took+=("$ms $cpu $kind/$name")
  done
}
running=0
for ((k = 0; k < ${#queue[@]}; k++)); do
  while [ "$running" -ge "$jobs" ]; do
    wait -n
    running=$((running - 1))
    report
  done
  read -r kind path name <<< "${queue[k]}"
  "$kind" "$k" "$path" "$name" > "$res/$k.out" 2>&1 &
  running=$((running + 1))
done
wait
report
# a test that left no result (its shell was killed) failed
for ((k = 0; k < ${#queue[@]}; k++)); do
  [ -n "${shown[k]:-}" ] && continue
  read -r kind _ name <<< "${queue[k]}"
  echo "== $kind $name: no result"
  cat "$res/$k.out"
  fail=$((fail + 1))
  failed_progs+=("$kind/$name(lost)")
done

if [ ${#took[@]} -gt 0 ]; then
  echo "slowest (wall, cpu):"
  printf '%s\n' "${took[@]}" | sort -rn | head -15 | awk '{ printf "  %7.1f s %7.1f s  %s\n", $1 / 1000, $2 / 1000, $3 }'
fi
ms=$((($(date +%s%N) - t_all) / 1000000))
echo "time: $((ms / 1000)) s in all, $jobs at a time"
[ ${#failed_progs[@]} -gt 0 ] && echo "failed: ${failed_progs[*]}"
echo "total: $pass passed, $fail failed, $skip skipped"
[ "$fail" -eq 0 ]
