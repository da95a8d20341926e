#!/usr/bin/env bash
# tests/integ/farmd_conns.sh - issue 30 cases 2, 3 and 5 against a running
# slimfarmd over loopback, one line per probe:
#   case | what the clients do | what they got
# 2: 256 keyless keep-alive connections from 8 addresses hold every slot
#    they can get; a keyed request is still answered.
# 3: 256 event streams on a read-only key, then 32 streams from one address
#    on the read-write key; the read-write key, from that address too, is
#    still answered, and a stream carries the heartbeat comment.
# 5: requests framed two ways (Transfer-Encoding with Content-Length, a
#    space before the colon, a folded line, control bytes in a value) are
#    answered 400 and their connection closed; clean ones still work.
# And `slimfarm watch` reconnects when the daemon ends a stream.
# No timing is asserted: each probe waits for its answer with a deadline.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/daemon.sh"
D=$BUILD/bin/slimfarmd
PY=/usr/bin/python3
LIB=$(cd "$(dirname "$0")/lib" && pwd)
tmp=$(mktemp -d)
pid=
cleanup() { [ -n "$pid" ] && kill -9 "$pid" 2>/dev/null; wait 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
fail() { echo "FAIL: $*"; echo "--- daemon log (tail)"; tail -30 "$tmp/log" 2>/dev/null; exit 1; }
[ -x "$PY" ] || { echo "SKIP: no python3"; exit 77; }

RW=rw-key-0123456789abcdef
RO=ro-key-0123456789abcdef
{
  printf '[farm]\nlisten: 127.0.0.1:0\ndata_dir: %s/data\napi_keys: %s\n' "$tmp" "$RW"
  printf 'api_keys_readonly: %s\nprofiles_dir: %s/config\n' "$RO" "$PWD"
  printf '[printer mk3]\ndriver: marlin\nport: pty:/dev/null\nmaterial: PLA\n'
} > "$tmp/farm.ini"
start() {
  daemon_start "$tmp/farm.ini" "$tmp/log" || fail "daemon did not come up"
  for _ in $(seq 200); do
    curl -s -o /dev/null -H "X-Api-Key: $RW" "$SLIMFARM_URL/api/printers" && return 0
    sleep 0.05
  done
  fail "daemon did not come up"
}
restart() { kill -9 "$pid"; wait "$pid" 2>/dev/null; pid=; start; }
probe() { # probe NAME: run the python probe NAME, fail unless it prints ok
  "$PY" - "$http_port" "$RW" "$RO" "$LIB" "$1" > "$tmp/$1.out" 2>&1 <<'PYEOF'
import sys
port, rw, ro, lib, name = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5]
sys.path.insert(0, lib)
import hostile as H

def case2():
    socks, seen = H.keyless_keepalive(port, 256, 8)
    ok = H.keyed_ok(port, rw)
    print("256 keyless keep-alive GET /favicon.svg from 8 addresses: %s; keyed GET /api/printers %s"
          % (seen, "200" if ok else "NOT answered"))
    H.close_all(socks)
    return ok

def case3_ro():
    socks, seen = H.streams(port, ro, 256, ["127.0.0.%d" % (2 + i) for i in range(8)])
    ok = H.keyed_ok(port, rw)
    print("256 /api/events on the read-only key: %s; read-write GET /api/printers %s"
          % (seen, "200" if ok else "NOT answered"))
    # the heartbeat: an accepted stream carries an SSE comment line
    beat = False
    for s in socks[:1]:
        data = b""
        try:
            while b"\n: keepalive\n" not in data:
                chunk = s.recv(4096)
                if not chunk:
                    break
                data += chunk
        except OSError:
            pass
        beat = b"\n: keepalive\n" in data
    print("an open stream's heartbeat comment: %s" % ("seen" if beat else "NOT seen"))
    H.close_all(socks)
    return ok and beat

def case3_addr():
    socks, seen = H.streams(port, rw, 32, ["127.0.0.10"])
    ok = H.keyed_ok(port, rw, "127.0.0.10")
    print("32 /api/events from 127.0.0.10 on the read-write key: %s; "
          "GET /api/printers from 127.0.0.10 %s" % (seen, "200" if ok else "NOT answered"))
    H.close_all(socks)
    return ok

def case5():
    k = ("X-Api-Key: %s\r\n" % rw).encode()
    get = b"GET /api/printers HTTP/1.1\r\nHost: x\r\n" + k
    close = b"Connection: close\r\n\r\n"
    smuggled = b"GET /api/printers HTTP/1.1\r\nHost: x\r\n" + k + close
    probes = [
        ("Transfer-Encoding: chunked and Content-Length: 5, a request after the body",
         b"POST /api/jobs/999/cancel HTTP/1.1\r\nHost: x\r\n" + k +
         b"Content-Length: 5\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n" + smuggled, [400]),
        ("'Transfer-Encoding : chunked' (space before the colon) with Content-Length",
         b"POST /api/jobs/999/cancel HTTP/1.1\r\nHost: x\r\n" + k +
         b"Content-Length: 5\r\nTransfer-Encoding : chunked\r\n\r\n0\r\n\r\n" + smuggled, [400]),
        ("a folded header line (obs-fold)", get + b"X-Note: a\r\n b\r\n" + close, [400]),
        ("a folded line holding a token only", get + b"X-Note:\r\n\tchunked\r\n" + close, [400]),
        ("a NUL inside X-Api-Key",
         b"GET /api/printers HTTP/1.1\r\nHost: x\r\nX-Api-Key: " + rw.encode() +
         b"\x00junk\r\n" + close, [400]),
        ("a lone CR inside a value", get + b"X-Note: a\rb\r\n" + close, [400]),
        ("a \\x01 inside a value", get + b"X-Note: a\x01b\r\n" + close, [400]),
        ("a header line ended by a bare LF", get + b"X-Note: a\n" + close, [400]),
        ("Transfer-Encoding: gzip", b"POST /api/jobs/999/cancel HTTP/1.1\r\nHost: x\r\n" + k +
         b"Transfer-Encoding: gzip\r\n\r\n", [501]),
        # clean requests are still served: two pipelined, a chunked body
        ("two clean pipelined GETs", get + b"\r\n" + smuggled, [200, 200]),
        ("a clean chunked PATCH", b"PATCH /api/jobs/999 HTTP/1.1\r\nHost: x\r\n" + k +
         b"Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n" + close +
         b"f\r\n{\"priority\": 3}\r\n0\r\n\r\n", [404]),
    ]
    ok = True
    for what, raw, want in probes:
        got = H.raw_responses(port, raw)
        good = got == want
        ok = ok and good
        print("%-78s %s%s" % (what, got, "" if good else "  (want %s, then closed)" % want))
    return ok

print("ok" if globals()[name]() else "FAILED")
PYEOF
  sed -e 's/^/  /' "$tmp/$1.out"
  tail -n 1 "$tmp/$1.out" | grep -qx ok || failed="$failed $1"
}

failed=
start
echo "case 5: framing"
probe case5
echo "case 2: keyless clients"
probe case2
restart
echo "case 3: event streams"
probe case3_ro
restart
probe case3_addr
# slimfarm watch, when a stream ends (its lifetime is over), reconnects
# after the last whole event: a stand-in server ends the first stream in
# the middle of an event, then checks the second request's Last-Event-ID
echo "watch: a stream that ends"
"$PY" - > "$tmp/sse.port" 2> "$tmp/sse.err" <<'PYEOF' &
import socket, sys
srv = socket.socket()
srv.bind(("127.0.0.1", 0))
srv.listen(5)
srv.settimeout(30)
print(srv.getsockname()[1], flush=True)
for n in range(2):
    c, _ = srv.accept()
    head = b""
    while b"\r\n\r\n" not in head:
        head += c.recv(4096)
    lei = [l for l in head.decode().split("\r\n") if l.lower().startswith("last-event-id:")]
    sys.stderr.write("request %d: %s\n" % (n + 1, lei[0] if lei else "no Last-Event-ID"))
    c.sendall(b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nConnection: close\r\n\r\n" +
              (b'id: %d\nevent: job-add\ndata: {"job_id": %d}\n\nid: 99\nevent: job-add\ndata: {"jo'
               % (5 + n, 5 + n)))
    c.close()
PYEOF
spid=$!
for _ in $(seq 100); do [ -s "$tmp/sse.port" ] && break; sleep 0.05; done
timeout 30 "$BUILD/bin/slimfarm" watch --count 2 --url "http://127.0.0.1:$(cat "$tmp/sse.port")" \
  --key "$RW" > "$tmp/watch.out" 2>&1
rc=$?
wait $spid
sed -e 's/^/  /' "$tmp/sse.err"
grep -q "request 2: Last-Event-ID: 5" "$tmp/sse.err" && [ $rc = 0 ] &&
  [ "$(grep -c 'job-add' "$tmp/watch.out")" = 2 ] || failed="$failed watch($rc: $(tr '\n' ' ' < "$tmp/watch.out"))"

[ -z "$failed" ] || fail "$failed"
kill -TERM "$pid"; wait "$pid"; rc=$?; pid=
[ $rc = 0 ] || fail "SIGTERM: exit $rc"
echo "farmd_conns: ok"
