#!/usr/bin/env bash
# bench_api_conns.sh BUILD - a keyed client's GET /api/printers latency with
# and without hostile clients attached (issue 30), side by side, and the
# daemon's RSS before and after.
#
# One slimfarmd on loopback (one printer, no jobs).  Clean: BENCH_N keyed
# GETs, one new connection each (as curl or a script makes them), one after
# another.  Then attached, from 127.0.0.2..9 (every 127/8 address is
# loopback): BENCH_HOSTILE keyless clients, half trickling a request head
# one byte a second, half keep-alive fetching /favicon.svg every 15 s, and
# BENCH_HOSTILE event streams on a read-only key; a thread keeps them at
# it and reconnects each one the daemon closes (at most once a second per
# client), so the daemon's caps are pushed all the time.  Then the same
# BENCH_N keyed GETs.  A GET not answered within 5 s counts as 5000 ms and
# as "unanswered"; a phase also ends after BENCH_SECS.
#
# BENCH_BASE=path/to/another/slimfarmd runs the same against that daemon
# too (say main's, to show the lock-out) and prints both rows.
# BENCH_N (300), BENCH_HOSTILE (300), BENCH_SECS (60).
set -u
umask 077 # slimfarmd refuses a farm.ini holding keys that others can read
build=${1:-build/rel}
PY=/usr/bin/python3
[ -x "$PY" ] || { echo "bench_api_conns: no python3, skipped"; exit 0; }
LIB=$(cd "$(dirname "$0")/../integ/lib" && pwd)
D=$build/bin/slimfarmd
. "$LIB/daemon.sh"
tmp=$(mktemp -d)
pid=
cleanup() { [ -n "$pid" ] && kill -9 "$pid" 2>/dev/null; wait 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
RW=rw-key-0123456789abcdef
RO=ro-key-0123456789abcdef

run() { # run LABEL DAEMON: one row
  local label=$1
  D=$2
  rm -rf "$tmp/data"
  {
    printf '[farm]\nlisten: 127.0.0.1:0\ndata_dir: %s/data\napi_keys: %s\n' "$tmp" "$RW"
    printf 'api_keys_readonly: %s\nprofiles_dir: %s/config\n' "$RO" "$PWD"
    printf '[printer mk3]\ndriver: marlin\nport: pty:/dev/null\nmaterial: PLA\n'
  } > "$tmp/farm.ini"
  daemon_start "$tmp/farm.ini" "$tmp/log" || { echo "$label: daemon did not start"; return; }
  "$PY" - "$http_port" "$pid" "$RW" "$RO" "$LIB" "$label" \
    "${BENCH_N:-300}" "${BENCH_HOSTILE:-300}" "${BENCH_SECS:-60}" <<'PYEOF'
import multiprocessing, os, sys, time, socket
port, dpid, rw, ro, lib, label = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5], sys.argv[6]
n, hostile, secs = int(sys.argv[7]), int(sys.argv[8]), float(sys.argv[9])
sys.path.insert(0, lib)
import hostile as H

def rss_kb(field="VmRSS"):
    for line in open("/proc/%s/status" % dpid):
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0

def nfds():
    return len(os.listdir("/proc/%s/fd" % dpid))

def keyed(n):
    """n keyed GETs, one each 50 ms (the attack goes on between them)."""
    lat, bad, end = [], 0, time.monotonic() + secs
    for i in range(n):
        if time.monotonic() > end:
            break
        if i:
            time.sleep(0.05)
        t0 = time.monotonic()
        ok = H.keyed_ok(port, rw, timeout=5)
        lat.append((time.monotonic() - t0) * 1000 if ok else 5000.0)
        bad += not ok
    lat.sort()
    pick = lambda q: lat[min(len(lat) - 1, int(q * len(lat)))]
    return pick(0.5), pick(0.99), len(lat), bad

# A hostile client: (kind, source address, socket or None, next action time)
ADDRS = ["127.0.0.%d" % (2 + i) for i in range(8)]
clients = []
for i in range(hostile):
    clients.append(["slow" if i % 2 else "keep", ADDRS[i % 8], None, 0.0])
    clients.append(["stream", ADDRS[i % 8], None, 0.0])
stop = multiprocessing.Event()
ready = multiprocessing.Event()

def act(c, now):
    kind, src, s, _ = c
    try:
        if s is None:
            s = H.connect(port, src, timeout=2)
            s.setblocking(False)
            if kind == "slow":
                s.sendall(b"GET /favicon.svg HTTP/1.1\r\nHost: x\r\n")
            elif kind == "keep":
                s.sendall(b"GET /favicon.svg HTTP/1.1\r\nHost: x\r\n\r\n")
            else:
                s.sendall(("GET /api/events HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\n\r\n"
                           % ro).encode())
            c[2], c[3] = s, now + (1 if kind == "slow" else 15)
            return
        try:
            while True: # drain what the daemon sent; b"" is its close
                if not s.recv(65536):
                    raise OSError("closed")
        except BlockingIOError:
            pass
        if now >= c[3]:
            if kind == "slow":
                s.sendall(b"X")
                c[3] = now + 1
            elif kind == "keep":
                s.sendall(b"GET /favicon.svg HTTP/1.1\r\nHost: x\r\n\r\n")
                c[3] = now + 15
            else:
                c[3] = now + 15
    except OSError:
        if c[2] is not None:
            try:
                c[2].close()
            except OSError:
                pass
        c[2], c[3] = None, now + 1 # reconnect in a second

def harass():
    """In a process of its own, so the measuring one never waits for it."""
    while not stop.is_set():
        now = time.monotonic()
        for c in clients:
            if c[2] is not None or now >= c[3]:
                act(c, now)
        if not any(c[3] == 0.0 for c in clients):
            ready.set() # every client has tried once
        stop.wait(0.2)
    H.close_all([c[2] for c in clients if c[2] is not None])

rss0, fd0 = rss_kb(), nfds()
clean = keyed(n)
p = multiprocessing.Process(target=harass)
p.start()
ready.wait(60)
time.sleep(2) # the daemon's answers and closes are in, the trickles under way
fd1 = nfds()
under = keyed(n)
rss1, hwm, fd2 = rss_kb(), rss_kb("VmHWM"), nfds()
stop.set()
p.join()
fmt = lambda r: "p50 %6.1f ms  p99 %6.1f ms  (%d GETs, %d unanswered)" % r
print("%-5s clean:    %s  RSS %6d KiB, %3d fds" % (label, fmt(clean), rss0, fd0))
print("%-5s attacked: %s  RSS %6d KiB, %3d fds (%d as the measuring began); peak RSS %d KiB"
      % (label, fmt(under), rss1, fd2, fd1, hwm))
PYEOF
  kill -TERM "$pid"; wait "$pid" 2>/dev/null; pid=
}

echo "keyed GET /api/printers, new connection each; attacked = ${BENCH_HOSTILE:-300} keyless (slow heads, keep-alive) + ${BENCH_HOSTILE:-300} event streams"
run this "$D"
[ -n "${BENCH_BASE:-}" ] && run base "$BENCH_BASE"
exit 0
