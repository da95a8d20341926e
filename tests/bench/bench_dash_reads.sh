#!/usr/bin/env bash
# bench_dash_reads.sh BUILD [BASE_BUILD] - what the dashboard's reads cost:
# GET /api/printers on 24 idle simulated printers (one simulator process
# serves them) and GET /api/jobs?limit=500&order=desc over a history of
# BENCH_JOBS (10,000) finished jobs (fill_jobs), each BENCH_N (200) times
# on one keep-alive connection, from a farm whose database is written
# before it starts.  GET /api/printers now reads each printer's bed, held
# job and last print from the store, and a jobs page looks up each job's
# last printer: with BASE_BUILD (say main's build/rel) the same runs on it
# too, side by side, and the ratios are printed.  Figures only: it never
# fails on time.  Loopback only; about a minute per build.
set -u
build=${1:-build/rel}
base=${2:-}
jobs=${BENCH_JOBS:-10000}
n=${BENCH_N:-200}

# one build's run: "printers_ms jobs_ms" (mean ms per request)
measure() {
  (
    BUILD=$1
    . "$(dirname "$0")/../integ/lib/farm.sh"
    fail() { echo "bench_dash_reads: $*" >&2; exit 1; }
    for b in "$D" "$C" "$S"; do [ -x "$b" ] || fail "$b not built"; done
    "$S" marlin --baud 1000000 --advanced-ok --speed 100 --count 24 > "$tmp/sims.out" 2> "$tmp/sims.err" &
    sims+=($!)
    for _ in $(seq 600); do [ "$(cat "$tmp/sims.out" 2> /dev/null | wc -l)" -ge 24 ] && break; sleep 0.05; done
    {
      printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
      i=0
      while read -r a; do
        case "$a" in /dev/*) a="pty:$a" ;; esac
        printf '[printer p%d]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' "$i" "$a"
        i=$((i + 1))
      done < "$tmp/sims.out"
    } > "$tmp/farm.ini"
    start_daemon
    kill -TERM "$pid"; wait "$pid"; pid=
    fill_jobs "$tmp/data/slimfarm.db" "$jobs" || fail "fill the store"
    start_daemon
    wait_for 120 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 24 ]" || fail "printers: $("$C" printers)"
    /usr/bin/python3 - "$http_port" "$RW" "$n" <<'PY'
import http.client, sys, time
port, key, n = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
out = []
for path in ("/api/printers", "/api/jobs?limit=500&order=desc&state=done,failed,cancelled"):
    t0 = time.monotonic()
    for _ in range(n):
        conn.request("GET", path, headers={"X-Api-Key": key})
        r = conn.getresponse()
        r.read()
        if r.status != 200:
            sys.exit("GET %s: %d" % (path, r.status))
    out.append("%.2f" % ((time.monotonic() - t0) * 1000 / n))
print(" ".join(out))
PY
    kill -TERM "$pid"; wait "$pid" 2> /dev/null; pid=
  )
}

this=$(measure "$build") || exit 1
printf '%-28s %14s %22s\n' build "printers (ms)" "jobs page of 500 (ms)"
printf '%-28s %14s %22s\n' "$build" $this
if [ -n "$base" ]; then
  that=$(measure "$base") || exit 1
  printf '%-28s %14s %22s\n' "$base" $that
  set -- $this $that
  awk -v a="$1" -v b="$2" -v c="$3" -v d="$4" \
    'BEGIN { printf "%-28s %14.2f %22.2f\n", "ratio (this / base)", a / c, b / d }'
fi
