#!/usr/bin/env bash
# tests/integ/farmd_jobs_page.sh - GET /api/jobs in pages (issue 30): over a
# history of 1,500 jobs (written into the stopped daemon's database, then
# checked by --fsck), a read-only key's walk by cursor returns every job exactly once in
# bounded pages, and jobs submitted during the walk at its end; filters by
# state, printer and time and order=desc agree with the store; bad
# parameters get 400 naming the parameter; `slimfarm jobs` lists them all
# and /metrics counts them.  Real daemon over loopback, real SQLite (or PostgreSQL:
# make check-pg).
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
N=1500

RO=ro-key-0123456789abcdef
# one printer, offline (the history names it; nothing prints)
printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\napi_keys_readonly: %s\n%s\n' \
  "$port" "$tmp" "$RW" "$RO" '[printer mk3]' > "$tmp/farm.ini"
printf 'driver: marlin\nport: pty:/dev/null\nmaterial: PLA\n' >> "$tmp/farm.ini"
start_daemon
kill -TERM $pid; wait $pid; pid=
fill_jobs "$(daemon_db "$tmp/farm.ini")" $N || fail "fill the store"
out=$("$D" -c "$tmp/farm.ini" --fsck 2>&1) || fail "--fsck of the filled store: $out"
start_daemon
tetra "$tmp/t.stl" 10

PORT=$http_port RW=$RW RO=$RO N=$N C="$C" T="$tmp/t.stl" /usr/bin/python3 - <<'PY' || fail "paging"
import json, os, subprocess, sys, urllib.error, urllib.request
port, key, n = int(os.environ["PORT"]), os.environ["RO"], int(os.environ["N"])
base = "http://127.0.0.1:%d" % port

def check(cond, what):
    if not cond:
        sys.exit("FAIL: " + what)

def get(path):
    r = urllib.request.Request(base + path, headers={"X-Api-Key": key})
    try:
        with urllib.request.urlopen(r, timeout=60) as f:
            return f.status, f.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()

def submit():
    out = subprocess.run([os.environ["C"], "submit", os.environ["T"]], capture_output=True,
                         text=True, env=dict(os.environ, SLIMFARM_URL=base,
                                             SLIMFARM_API_KEY=os.environ["RW"]))
    check(out.returncode == 0, "submit: " + out.stdout + out.stderr)

def walk(first, added=0):
    seen, pages, nxt, biggest = [], 0, first, 0
    while nxt:
        st, body = get(nxt)
        check(st == 200, "GET %s: %d %s" % (nxt, st, body[:200]))
        biggest = max(biggest, len(body))
        d = json.loads(body)
        check(len(d["jobs"]) <= 100 or "limit=" in nxt, "a default page holds %d jobs" % len(d["jobs"]))
        seen += [j["id"] for j in d["jobs"]]
        pages += 1
        if pages == 1:
            for _ in range(added):
                submit()
        check(("next" in d) and (d["next"] is None) == (d["next_cursor"] is None), "next: %s" % d.keys())
        nxt = d["next"]
        check(pages < 1000, "the walk does not end")
    return seen, pages, biggest

# the default walk: pages of 100, each job once, in order; 3 submitted meanwhile come last
seen, pages, biggest = walk("/api/jobs", added=3)
check(len(seen) == len(set(seen)), "a job came twice")
check(seen == sorted(seen), "not oldest first")
check(seen == list(range(1, n + 4)), "jobs missing: %d of %d" % (len(seen), n + 3))
check(pages == (n + 3 + 99) // 100, "%d pages" % pages)
check(biggest < 512 * 1024, "a page of %d bytes" % biggest)
# newest first in pages of 500 (the most), with a state filter
seen, pages, _ = walk("/api/jobs?order=desc&limit=500&state=done,cancelled")
check(seen == sorted(seen, reverse=True) and len(seen) == n, "desc walk: %d" % len(seen))
check(pages == 3, "desc pages %d" % pages)
st, body = get("/api/jobs?state=cancelled&limit=500")
d = json.loads(body)
check(st == 200 and all(j["state"] == "cancelled" for j in d["jobs"]), "state filter")
seen, _, _ = walk("/api/jobs?state=cancelled")
check(len(seen) == n // 3, "cancelled %d" % len(seen))
seen, _, _ = walk("/api/jobs?printer=mk3&limit=500")
check(len(seen) == n - n // 3, "printed on mk3: %d" % len(seen))
# the submitted jobs, whatever became of them, and by their states: every
# state, for they move on (queued, preparing, ready ...) between two reads
d = json.loads(get("/api/jobs?order=desc&limit=3")[1])
check([j["id"] for j in d["jobs"]] == [n + 3, n + 2, n + 1], "newest first %s" % d)
states = ["queued", "preparing", "ready", "printing", "paused", "done", "failed", "cancelled",
          "interrupted"]
seen, _, _ = walk("/api/jobs?state=" + ",".join(states))
check([i for i in seen if i > n] == [n + 1, n + 2, n + 3], "by state %s: %s" % (states, seen[-5:]))
# time: the history was written a minute apart, oldest N minutes ago
d = json.loads(get("/api/jobs?limit=1&order=desc&state=done,cancelled")[1])
t = d["jobs"][0]["updated_ms"]
seen, _, _ = walk("/api/jobs?since=%d&until=%d&state=done,cancelled" % (t - 10 * 60000 + 1, t + 1))
check(len(seen) == 10, "a ten-minute window holds %d jobs" % len(seen))

# bad parameters: 400 naming the parameter
for q, name in [("limit=0", "limit"), ("limit=501", "limit"), ("limit=x", "limit"),
                ("state=bogus", "state"), ("state=done,", "state"), ("cursor=zz", "cursor"),
                ("cursor=d5", "cursor"), ("order=up", "order"), ("since=-1", "since"),
                ("since=10&until=5", "until"), ("printer=", "printer"), ("limit=5&limit=6", "limit"),
                ("colour=red", "colour")]:
    st, body = get("/api/jobs?" + q)
    check(st == 400 and ("'%s'" % name) in json.loads(body)["error"], "%s: %d %s" % (q, st, body))
PY

out=$("$C" jobs) || fail "slimfarm jobs: $out"
[ "$(grep -c 'bracket-' <<< "$out")" -eq $N ] || fail "slimfarm jobs lists $(grep -c 'bracket-' <<< "$out") of $N"
[ "$("$C" jobs --state cancelled | grep -c ' cancelled ')" -eq $((N / 3)) ] || fail "slimfarm jobs --state"
m=$(curl -sf -H "X-Api-Key: $RW" "$SLIMFARM_URL/metrics") || fail "/metrics"
grep -qx "slimfarm_jobs{state=\"done\"} $((N - N / 3))" <<< "$m" || fail "metrics: $(grep slimfarm_jobs <<< "$m")"
# (a store host's series name its host too)
grep -qx "slimfarm_prints_total{printer=\"mk3\"${DAEMON_HOST:+,host=\"$DAEMON_HOST\"},outcome=\"done\"} $((N - N / 3))" \
  <<< "$m" || fail "metrics prints: $(grep slimfarm_prints_total <<< "$m")"
echo "farmd_jobs_page: ok"
