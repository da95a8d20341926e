# tests/integ/lib/farm.sh - helpers for the farm scenarios that print on
# simulated printers: start sims and the daemon, make parts, talk to the
# API, and check each printer's executed log against the stored G-code of
# the prints it ran (check_farm_logs).  Sourced, not run.  Needs $BUILD;
# sets $tmp (removed on exit), $RW, SLIMFARM_API_KEY, and $port: 0, the
# port a test's farm.ini listens on (the kernel picks one, lib/daemon.sh);
# start_daemon sets $http_port and SLIMFARM_URL to the daemon's.
set -u
umask 077 # slimfarmd refuses a farm.ini holding keys that others can read
. "$(dirname "${BASH_SOURCE[0]}")/daemon.sh"
D=$BUILD/bin/slimfarmd
C=$BUILD/bin/slimfarm
S=$BUILD/bin/slimfarm-sim
tmp=$(mktemp -d)
pid=
sims=()
cleanup() {
  [ -n "$pid" ] && kill -9 "$pid" 2>/dev/null
  for p in "${sims[@]}"; do kill "$p" 2>/dev/null; done
  wait 2>/dev/null
  [ -n "${KEEP_TMP:-}" ] && echo "kept $tmp" || rm -rf "$tmp"
}
trap cleanup EXIT
fail() {
  echo "FAIL: $*"; echo "--- daemon log (tail)"; tail -30 "$tmp/log" 2>/dev/null
  sim_tails
  exit 1
}

# sim_tails: each simulated Marlin's side of a failure, after a SIGTERM (a sim
# prints its counters on exit): how many bytes it took from the host and how
# many commands it ran, and the last commands it ran.  A stream that stalls
# shows here whether the host's lines ever reached the printer.
sim_tails() {
  local a n v
  for a in "$tmp"/*.addr; do
    [ -e "$a" ] || return 0
    n=$(basename "$a" .addr) v=sim_$n
    [ -n "${!v:-}" ] && { kill "${!v}" && wait "${!v}"; } 2>/dev/null
    echo "--- sim $n: $(tail -n 2 "$tmp/$n.err" 2>/dev/null | tr '\n' ' ')"
    echo "    last commands run: $(tail -n 3 "$tmp/$n.log" 2>/dev/null | tr '\n' '|')"
  done
}

port=0
http_port=
RW=rw-key-0123456789abcdef
export SLIMFARM_API_KEY=$RW

# start_sim NAME ARGS...: a fast simulated Marlin logging to $tmp/NAME.log; its
# address (pty:PATH or tcp://...) lands in $tmp/NAME.addr.
start_sim() {
  local name=$1; shift
  rm -f "$tmp/$name.out" # a restarted sim must not be read from its last run's file
  "$S" marlin --baud 1000000 --advanced-ok --log "$tmp/$name.log" "$@" \
    > "$tmp/$name.out" 2> "$tmp/$name.err" &
  sims+=($!)
  eval "sim_$name=$!"
  local end=$((SECONDS + 30))
  while [ ! -s "$tmp/$name.out" ] && [ $SECONDS -lt $end ]; do sleep 0.05; done
  local a; a=$(head -n 1 "$tmp/$name.out")
  [ -n "$a" ] || fail "sim $name did not start: $(cat "$tmp/$name.err")"
  case "$a" in /dev/*) a="pty:$a" ;; esac
  echo "$a" > "$tmp/$name.addr"
}

# stop_sims: SIGTERM every simulator and wait (their logs are flushed on exit).
stop_sims() {
  for p in "${sims[@]}"; do kill "$p" 2>/dev/null; wait "$p" 2>/dev/null; done
  sims=()
}

# one_printer_ini NAME AUTO_EJECT: $tmp/farm.ini for one simulated Marlin
# NAME (started with start_sim) and the slicing profiles beside it; a test
# appends its own sections.
one_printer_ini() {
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW" > "$tmp/farm.ini"
  printf '[printer %s]\ndriver: marlin\nport: %s\nbaud: 1000000\nauto_eject: %s\n' \
    "$1" "$(cat "$tmp/$1.addr")" "$2" >> "$tmp/farm.ini"
  cp -r config/printers config/materials "$tmp/"
}

# start_daemon: slimfarmd on $tmp/farm.ini, logging to $tmp/log; each start
# (a restart too) listens on a port of its own, in $http_port and SLIMFARM_URL.
start_daemon() {
  daemon_start "$tmp/farm.ini" "$tmp/log" || fail "daemon did not come up"
  for _ in $(seq 200); do "$C" jobs >/dev/null 2>&1 && return 0; sleep 0.05; done
  fail "daemon did not answer on $SLIMFARM_URL"
}

# pin_port: make the config listen on the running daemon's port, so a
# restart by a program that keeps the URL (the browser test) comes back on it.
pin_port() {
  sed -i "s/^listen: \(.*\):0\$/listen: \1:$http_port/" "$tmp/farm.ini"
}

# tetra FILE SIZE: a right tetrahedron with legs of SIZE mm (a small, quick part).
tetra() {
  local s=$2
  printf 'solid t\nfacet normal 0 0 -1\nouter loop\nvertex 0 0 0\nvertex 0 %s 0\nvertex %s 0 0\nendloop\nendfacet\nfacet normal 0 -1 0\nouter loop\nvertex 0 0 0\nvertex %s 0 0\nvertex 0 0 %s\nendloop\nendfacet\nfacet normal -1 0 0\nouter loop\nvertex 0 0 0\nvertex 0 0 %s\nvertex 0 %s 0\nendloop\nendfacet\nfacet normal 1 1 1\nouter loop\nvertex %s 0 0\nvertex 0 %s 0\nvertex 0 0 %s\nendloop\nendfacet\nendsolid t\n' \
    "$s" "$s" "$s" "$s" "$s" "$s" "$s" "$s" "$s" > "$1"
}

api() { curl -sf -H "X-Api-Key: $RW" "$SLIMFARM_URL$1"; }

# api_jobs [QUERY]: every job that GET /api/jobs?QUERY lists, walking its
# pages ("next"), as one {"jobs": [...]} on stdout.
api_jobs() {
  /usr/bin/python3 - "$SLIMFARM_URL" "$RW" "${1:-}" <<'PY'
import json, sys, urllib.request
url, key, q = sys.argv[1:4]
nxt, jobs = "/api/jobs?limit=500" + ("&" + q if q else ""), []
while nxt:
    r = urllib.request.Request(url + nxt, headers={"X-Api-Key": key})
    d = json.load(urllib.request.urlopen(r, timeout=60))
    jobs += d["jobs"]
    nxt = d["next"]
print(json.dumps({"jobs": jobs}))
PY
}

# fill_jobs DB N: N finished jobs (two in three done on printer "mk3" with
# their print, the others cancelled) written straight into a stopped
# daemon's database DB (SQLite's file, or a postgresql:// URL: daemon_db), as
# its schema wants them: a farm's history, in seconds rather than hours.
fill_jobs() {
  /usr/bin/python3 - "$1" "$2" <<'PY'
import hashlib, sqlite3, subprocess, sys, time
target, n = sys.argv[1], int(sys.argv[2])
now = int(time.time() * 1000)
sha = hashlib.sha256(b"history").hexdigest()
JOB = ("INSERT INTO jobs(name, file_sha, gcode_sha, state, method, deviation_mm, overhang_deg,"
       " copies, copies_done, max_retries, material, target_printer, target_group, priority,"
       " reason, created_ms, updated_ms, gcode_lines, filament_g)"
       " VALUES(%s,%s,%s,%s,'orient',0.5,45,1,%s,2,'PLA','','',0,%s,%s,%s,5000,3.5)")
PRINT = ("INSERT INTO prints(job_id, copy, printer, material, start_line, lines_acked,"
         " started_ms, ended_ms, outcome) %s 1,'mk3','PLA',1,5000,%s,%s,'done'")
def rows():
    for i in range(n):
        done = i % 3 != 2
        t = now - (n - i) * 60000
        yield done, t, ("bracket-%05d.stl" % i, sha, sha, "done" if done else "cancelled",
                        1 if done else 0, "" if done else "cancelled by an operator", t, t)
if target.startswith("postgresql://"): # one transaction through psql; a print names its job
    q = lambda v: str(v) if isinstance(v, int) else "'" + v.replace("'", "''") + "'"
    sql = ["BEGIN;", "INSERT INTO files(sha256, size, created_ms) VALUES(%s, 7, %d)"
           " ON CONFLICT DO NOTHING;" % (q(sha), now)]
    for done, t, r in rows():
        job = JOB % tuple(q(v) for v in r)
        sql.append("WITH j AS (%s RETURNING id) %s FROM j;" % (job, PRINT % ("SELECT id,", t, t + 30000))
                   if done else job + ";")
    sql.append("COMMIT;")
    subprocess.run(["psql", "-q", "-v", "ON_ERROR_STOP=1", target], input="\n".join(sql),
                   text=True, check=True, stdout=subprocess.DEVNULL)
    sys.exit(0)
db = sqlite3.connect(target)
db.execute("INSERT OR IGNORE INTO files(sha256, size, created_ms) VALUES(?, 7, ?)", (sha, now))
for done, t, r in rows():
    cur = db.execute(JOB % tuple("?" * 8), r)
    if done:
        db.execute(PRINT % ("VALUES(?,", "?", "?") + ")", (cur.lastrowid, t, t + 30000))
db.commit()
PY
}

# jq-free JSON field access: json EXPR reads the API reply on stdin.
json() { /usr/bin/python3 -c "import json,sys; d=json.load(sys.stdin); print($1)"; }

# submit ARGS...: submit a part, print its job id.
submit() {
  local out
  out=$("$C" submit "$@") || fail "submit $*: $out"
  echo "$out" | sed -n 's/^job \([0-9]*\) queued.*/\1/p'
}

job_state() { api "/api/jobs/$1" | json 'd["job"]["state"]'; }

# wait_for SECS CMD...: poll CMD until it succeeds.
wait_for() {
  local end=$((SECONDS + $1)); shift
  while [ $SECONDS -lt $end ]; do "$@" && return 0; sleep 0.1; done
  return 1
}

# fetch_jobs: every job with its print history from the API, into
# $tmp/job-ID.json (the list in $tmp/jobs.json), for the log checks.
fetch_jobs() {
  api_jobs > "$tmp/jobs.json"
  for j in $(json '" ".join(str(x["id"]) for x in d["jobs"])' < "$tmp/jobs.json"); do
    api "/api/jobs/$j" > "$tmp/job-$j.json"
  done
}

# check_farm_logs PRINTER...: each printer's executed log equals, in order,
# the commands of the stored G-code of every print it ran (from the API's
# print history).  Besides the driver's own queries, the only other lines
# allowed are the driver's documented sequences, each where it belongs:
# park/restore at a pause inside a print, the end sequence after a
# cancelled print's prefix, the resume preamble before a resumed print
# (started at its start_line).  A job line lost, repeated or reordered fails.
check_farm_logs() {
  fetch_jobs
  /usr/bin/python3 - "$tmp" "$@" <<'PY'
import glob, json, os, re, sys
tmp, printers = sys.argv[1], sys.argv[2:]
def commands(path):
    out = []
    for line in open(path, errors="replace"):
        c = re.sub(r";.*", "", line).strip()
        c = re.sub(r"\s+", " ", c)
        if c:
            out.append(c)
    return out
host = re.compile(r"^(M105|M110( N-?\d+)?|M115|M155 S\d+|M400)$")
# the driver's park/restore, end and resume sequences (drv_marlin.c)
driver = re.compile(r"^(M108|M83|M82|G90|G91|M84|M107|M104 S\d+|M140 S\d+|M109 S\d+|M190 S\d+|"
                    r"M106 S\d+|G28 X Y|G1 E-?2\.00 F(2400|300)|G1 Z-?[\d.]+ F600|"
                    r"G1 X-?[\d.]+ Y-?[\d.]+ F6000|G92 [EZ]-?[\d.]+|G1 F\d+)$")
prints = []
for f in glob.glob(os.path.join(tmp, "job-*.json")):
    d = json.load(open(f))
    for p in d["prints"]:
        prints.append((p["started_ms"], p["id"], p["printer"], p["outcome"], p["start_line"],
                       p["lines_acked"], p.get("gcode_sha") or d["job"]["gcode_sha"], d["job"]["id"]))
prints.sort()
bad = 0
ran_on = []  # lines each interrupted print ran past its last saved line
for name in printers:
    mine = [p for p in prints if p[2] == name]
    got = [c for c in commands(os.path.join(tmp, name + ".log")) if not host.match(c)]
    i, extra = 0, 0
    def fail(pid, job, what, w, want, start):
        global bad
        print("%s: print %d (job %d): %s at log line %d %r (job line %d of %d: %r)" %
              (name, pid, job, what, i + 1, got[i] if i < len(got) else None, start + w,
               start + len(want), want[w] if w < len(want) else None))
        bad += 1
    def expected(p):
        files = glob.glob(os.path.join(tmp, "data", "**", p[6] + "*"), recursive=True)
        return [c for c in commands(files[0]) if not host.match(c)][p[4]:]
    for k, (started, pid, _, outcome, start, acked, sha, job) in enumerate(mine):
        if bad:
            break
        files = glob.glob(os.path.join(tmp, "data", "**", sha + "*"), recursive=True)
        want = [c for c in commands(files[0]) if not host.match(c)][start:]
        # lines every print ran: all of a finished one, the acknowledged ones otherwise
        need = len(want) if outcome in ("done", "") else acked - start
        w = 0
        if start > 0:
            # a resumed print opens with the driver's resume preamble
            while i < len(got) and driver.match(got[i]) and got[i] != want[0]:
                i += 1
                extra += 1
        while w < need and i < len(got):
            if got[i] == want[w]:
                w += 1
            elif driver.match(got[i]):
                extra += 1  # resume preamble, park/restore around a pause
            else:
                break
            i += 1
        if w != need:
            fail(pid, job, "log differs", w, want, start)
            break
        if outcome in ("done", ""):
            continue
        # lines it ran past its last saved line, in order: a window in flight,
        # or more when the daemon was killed before saving its progress
        # (a resume, start > 0, opens with its preamble: never that case,
        # though its first lines are the ones this print ran on into)
        nxt = expected(mine[k + 1])[:8] if k + 1 < len(mine) and mine[k + 1][4] == 0 else None
        i0, w0 = i, w
        while i < len(got) and w < len(want) and got[i] == want[w]:
            i += 1
            w += 1
        # ... unless what followed was the next print itself, whole: a
        # network upload cut before its first line, the same G-code sent
        # again (a Marlin print that ran every line would have ended done)
        if w == len(want) and nxt and got[i0:i0 + len(nxt)] == nxt:
            i, w = i0, w0
            continue
        ran_on.append(w - w0)
        if outcome == "cancelled":
            # M108 (sent past the queue to break a heat wait), then the end
            # sequence: heaters off ... motors off
            while i < len(got) and got[i] == "M108":
                i += 1
                extra += 1
            if i >= len(got) or got[i] != "M104 S0":
                fail(pid, job, "no end sequence after cancel", w, want, start)
                break
            while i < len(got) and got[i] != "M84" and driver.match(got[i]):
                i += 1
                extra += 1
            i += 1
            extra += 1
    while not bad and i < len(got) and driver.match(got[i]):
        i += 1
        extra += 1
    if i < len(got) and not bad:
        print("%s: %d log lines after the last print: %r" % (name, len(got) - i, got[i:i + 3]))
        bad += 1
    print("  %s: %d prints, %d log lines, %d from the driver's own sequences" %
          (name, len(mine), len(got), extra))
if ran_on:
    print("  interrupted prints: %d; lines run past the saved line (re-run on resume): max %d, mean %.1f"
          % (len(ran_on), max(ran_on), sum(ran_on) / len(ran_on)))
sys.exit(1 if bad else 0)
PY
}
