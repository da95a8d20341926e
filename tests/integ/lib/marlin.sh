# tests/integ/lib/marlin.sh - helpers for the Marlin integration tests:
# make a job, start and stop a simulator, compare its log with the job.
# Sourced, not run.  Needs $BUILD; sets $TMP (removed on exit).
set -u
TMP=$(mktemp -d "${TMPDIR:-/tmp}/sfinteg.XXXXXX")
SIM_PID=
cleanup() { [ -n "$SIM_PID" ] && kill "$SIM_PID" 2>/dev/null; rm -rf "$TMP"; }
trap cleanup EXIT

# make_job FILE N: N moves around a circle, with comments and blank lines.
make_job() {
  awk -v n="$2" 'BEGIN {
    print "; job for the Marlin integration tests"; print "G28 ; home"; print "G90"; print "M82"
    print "M104 S200"; print "M109 S200"; print "G92 E0"; e = 0
    for (i = 0; i < n; i++) {
      e += 0.0213; a = i * 0.05
      if (i % 100 == 0) { printf ";LAYER:%d\n\n", i / 100 }
      printf "G1 X%.3f Y%.3f E%.5f F%d\n", 100 + 40 * cos(a), 100 + 40 * sin(a), e, 1800 + (i % 5) * 300
    } }' > "$1"
}

# commands FILE: the commands of a G-code file as a printer logs them.
commands() { sed -e 's/;.*//' -e 's/[[:space:]]*$//' -e 's/^[[:space:]]*//' "$1" | grep -v '^$'; }

# start_sim ARGS...: run slimfarm-sim marlin ARGS in the background; sets $PORT.
start_sim() {
  # the last run's file goes first: the shell truncates it in the background job, so the
  # wait below could see the old address and then read the file emptied (061 failed so)
  rm -f "$TMP/sim.out"
  "$BUILD/bin/slimfarm-sim" marlin "$@" > "$TMP/sim.out" 2> "$TMP/sim.err" &
  SIM_PID=$!
  # up to 30 s: a sanitizer build starting on a loaded machine can take seconds
  for _ in $(seq 600); do [ -s "$TMP/sim.out" ] && break; sleep 0.05; done
  PORT=$(head -n 1 "$TMP/sim.out")
  [ -n "$PORT" ] || { echo "simulator did not start (slimfarm-sim marlin $*): $(cat "$TMP/sim.err")"; ps -o pid,stat,etime,args -p "$SIM_PID" 2>&1 | tail -1; return 1; }
}

# stop_sim: SIGTERM, wait (the log is flushed on exit).
stop_sim() { kill "$SIM_PID"; wait "$SIM_PID" 2>/dev/null; SIM_PID=; }

# check_log JOB [GARBLED]: the sim log, less the host's own queries, equals
# the job's commands, each once, in order.  A probe garbled on the wire may
# still run as M105 ("M105k") or as another command ("M106"): the documented
# limit of unnumbered probes.  GARBLED (default 0) allows that many extra
# lines that are no line of the job at all: on a noisy link Marlin can run a
# piece of a line cut by its RX flush (drivers/README.md, "the head of a
# line"), which no host can prevent; the unit tests allow the same.  A lost,
# repeated or reordered job line always fails.
check_log() {
  commands "$1" > "$TMP/want"
  grep -v -E '^(M105([^0-9].*)?|M110( N-?[0-9]+)?|M115|M155 S[0-9]+|M400)$' "$TMP/log" |
    grep -v -E '^(.105|M.05|M1.5|M10.)$' > "$TMP/got"
  /usr/bin/python3 - "$TMP/want" "$TMP/got" "${2:-0}" <<'PY'
import sys
want = open(sys.argv[1]).read().splitlines()
got = open(sys.argv[2]).read().splitlines()
job = set(want)
allowed, garbled, i = int(sys.argv[3]), 0, 0
for line in got:
    if i < len(want) and line == want[i]:
        i += 1
    elif line not in job and garbled < allowed:
        garbled += 1
    else:
        sys.exit("executed log differs from the job at job line %d (%d wanted, %d ran): %r vs %r"
                 % (i + 1, len(want), len(got), line, want[i] if i < len(want) else None))
if i != len(want):
    sys.exit("executed log stops at job line %d of %d" % (i, len(want)))
if garbled:
    print("  %d garbled line piece(s) ran on the noisy link (allowed %d)" % (garbled, allowed))
PY
}
