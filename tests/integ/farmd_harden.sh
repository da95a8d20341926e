#!/usr/bin/env bash
# tests/integ/farmd_harden.sh - the probe of issue 16 against a running
# slimfarmd, items 5-13 and the minor ones, printing one line per request:
#   item | request | what it got
# A read-only key's multipart GET, 300 slow clients, a 10^5-face OBJ and a
# cancel and SIGTERM during its prepare, a truncated multipart body, a 3MF
# zip bomb (daemon peak RSS), refused options and tmp-* after kill -9, bad
# UTF-8 names, SSE Last-Event-ID above the newest, SIGHUP upload_max and a
# revoked key's stream, %00, two Content-Lengths, an empty file part.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/daemon.sh"
D=$BUILD/bin/slimfarmd
PY=/usr/bin/python3
tmp=$(mktemp -d)
pid=
cleanup() { [ -n "$pid" ] && kill -9 "$pid" 2>/dev/null; wait 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
fail() { echo "FAIL: $*"; echo "--- daemon log (tail)"; tail -30 "$tmp/log" 2>/dev/null; exit 1; }
row() { printf '%-5s | %-62s | %s\n' "$1" "$2" "$3"; }

port= U= # the daemon's, once started (a port the kernel picks: lib/daemon.sh)
RW=rw-key-0123456789abcdef
RO=ro-key-0123456789abcdef
config() { # config UPLOAD_MB WITH_RO
  {
    printf '[farm]\nlisten: 127.0.0.1:0\ndata_dir: %s/data\napi_keys: %s\n' "$tmp" "$RW"
    printf 'profiles_dir: %s/config\n' "$PWD"
    [ "$2" = 1 ] && printf 'api_keys_readonly: %s\n' "$RO"
    printf 'upload_max_mb: %s\n' "$1"
    printf '[printer mk3]\ndriver: marlin\nport: pty:/dev/null\nmaterial: PLA\n'
  } > "$tmp/farm.ini"
}
start() {
  daemon_start "$tmp/farm.ini" "$tmp/log" || fail "daemon did not come up"
  port=$http_port U=$SLIMFARM_URL
  for _ in $(seq 200); do
    curl -s -o /dev/null -H "X-Api-Key: $RW" "$U/api/jobs" && return 0
    sleep 0.05
  done
  fail "daemon did not come up"
}
nfiles() { find "$tmp/data/files" -type f | wc -l; }
# raw REQUEST-FILE: send it as is, print the status line's code and the body
raw() {
  exec 3<>"/dev/tcp/127.0.0.1/$port" || return 1
  cat "$1" >&3
  timeout 10 cat <&3 > "$tmp/raw.out"
  exec 3<&-
  head -n 1 "$tmp/raw.out" | cut -d' ' -f2
}
code() { curl -s -o "$tmp/r" -w '%{http_code}' "$@"; }
err() { sed -n 's/.*"error":"\([^"]*\)".*/\1/p' "$tmp/r" | head -c 90; }

config 2 1
start
printf 'solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n' > "$tmp/t.stl"
head -c 200000 /dev/zero | tr '\0' 'x' > "$tmp/big.stl"
head -c 1500000 /dev/zero | tr '\0' 'x' > "$tmp/big2.stl"

# 5: a read-only key's multipart body stores nothing, on any route and method
n0=$(nfiles)
c=$(code -X GET -H "X-Api-Key: $RO" -F "file=@$tmp/big.stl" "$U/api/jobs")
[ "$c" = 403 ] && [ "$(nfiles)" = "$n0" ] || fail "5: RO multipart GET: $c, files $n0 -> $(nfiles)"
row 5 "GET /api/jobs, read-only key, -F file=@big.stl (200 KB)" "$c $(err); files $n0 -> $(nfiles)"
c=$(code -X GET -H "X-Api-Key: $RO" -F "file=@$tmp/big.stl" "$U/api/nothing")
[ "$c" = 403 ] || fail "5: RO multipart on 404 route: $c"
row 5 "GET /api/nothing, read-only key, multipart" "$c"
c=$(code -X POST -H "X-Api-Key: $RW" -F "file=@$tmp/big.stl" "$U/api/jobs/1/cancel")
[ "$c" = 400 ] && [ "$(nfiles)" = "$n0" ] || fail "5: RW multipart on cancel: $c"
row 5 "POST /api/jobs/1/cancel, read-write key, multipart" "$c $(err)"

# 6: 300 clients with no key that never finish their request head
if [ -x "$PY" ]; then
  "$PY" - "$port" "$RW" > "$tmp/slow.out" 2>&1 <<'PYEOF'
import socket, sys, urllib.request
port, key = int(sys.argv[1]), sys.argv[2]
socks = []
for i in range(300):
    s = socket.socket()
    s.bind(("127.0.0.%d" % (2 + i % 10), 0))
    s.connect(("127.0.0.1", port))
    s.send(b"GET /api/jobs HTTP/1.1\r\nHost: x\r\n")
    socks.append(s)
ok = 0
for i in range(5):
    req = urllib.request.Request("http://127.0.0.1:%d/api/jobs" % port, headers={"X-Api-Key": key})
    try:
        ok += urllib.request.urlopen(req, timeout=20).status == 200
    except Exception as e:
        print("error:", e)
print("answered %d of 5" % ok)
PYEOF
  grep -q "answered 5 of 5" "$tmp/slow.out" || fail "6: $(cat "$tmp/slow.out")"
  row 6 "300 keyless clients from 10 addresses, head never finished; 5 GETs" "$(tail -n 1 "$tmp/slow.out")"
fi

# 8: a multipart body without its closing boundary
B=$'--XyZ\r\nContent-Disposition: form-data; name="file"; filename="two.obj"\r\n\r\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n'
printf 'POST /api/jobs HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\nContent-Type: multipart/form-data; boundary=XyZ\r\nContent-Length: %d\r\nConnection: close\r\n\r\n%s' "$RW" ${#B} "$B" > "$tmp/trunc.req"
n0=$(nfiles)
c=$(raw "$tmp/trunc.req")
[ "$c" = 400 ] && [ "$(nfiles)" = "$n0" ] || fail "8: truncated multipart: $c"
row 8 "POST /api/jobs, multipart without its closing boundary" "$c; files $n0 -> $(nfiles)"

# 10: refused options leave no file and no job
n0=$(nfiles)
c=$(code -H "X-Api-Key: $RW" -F "file=@$tmp/t.stl" -F 'options={"copies": 0}' "$U/api/jobs")
[ "$c" = 400 ] && [ "$(nfiles)" = "$n0" ] || fail "10: refused options: $c, files $n0 -> $(nfiles)"
row 10 "POST /api/jobs, options {\"copies\": 0}" "$c $(err); files $n0 -> $(nfiles)"

# 11: invalid UTF-8 and a multibyte name cut in the message
c=$(code -H "X-Api-Key: $RW" -F "file=@$tmp/t.stl;filename=$(printf 'bad\xff\xfe.stl')" "$U/api/jobs")
"$PY" -c 'import json,sys; json.load(open(sys.argv[1]))' "$tmp/r" 2>/dev/null || [ ! -x "$PY" ] || fail "11: body is not JSON"
[ "$c" = 400 ] || fail "11: invalid UTF-8 name: $c $(cat "$tmp/r")"
row 11 "file name 'bad\\xff\\xfe.stl'" "$c $(err)"
long=$(printf 'a%.0s\xc3\xa9' $(seq 60)).txt
c=$(code -H "X-Api-Key: $RW" -F "file=@$tmp/t.stl;filename=$long" "$U/api/jobs")
[ "$c" = 400 ] || fail "11: long name: $c $(cat "$tmp/r")"
"$PY" -c 'import json,sys; json.load(open(sys.argv[1]))' "$tmp/r" 2>/dev/null || [ ! -x "$PY" ] || fail "11: long name: body is not JSON"
row 11 "file name of 60 x 'a\\xc3\\xa9' + '.txt' (cut at 80 bytes)" "$c, valid JSON: $(err | cut -c1-24)..."

# minor: %00, two Content-Lengths, an empty file part
printf 'GET /api/jobs%%00/1 HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\nConnection: close\r\n\r\n' "$RW" > "$tmp/nul.req"
c=$(raw "$tmp/nul.req"); [ "$c" = 400 ] || fail "%00: $c"
row minor "GET /api/jobs%00/1" "$c"
printf 'PATCH /api/jobs/1 HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\nContent-Length: 15\r\nContent-Length: 16\r\nConnection: close\r\n\r\n{"priority": 3}' "$RW" > "$tmp/cl.req"
c=$(raw "$tmp/cl.req"); [ "$c" = 400 ] || fail "two Content-Length: $c"
row minor "PATCH with Content-Length: 15 and Content-Length: 16" "$c"
: > "$tmp/empty.stl"
c=$(code -H "X-Api-Key: $RW" -F "file=@$tmp/empty.stl" "$U/api/jobs")
[ "$c" = 400 ] || fail "empty file: $c"
row minor "POST /api/jobs, empty file part" "$c $(err)"

# 9: a 3MF zip bomb (200 MiB of XML whitespace) is refused at prepare in bounded memory
if [ -x "$PY" ]; then
  "$PY" - "$tmp/bomb.3mf" <<'PYEOF'
import sys, zipfile
with zipfile.ZipFile(sys.argv[1], "w", zipfile.ZIP_DEFLATED, compresslevel=9) as z:
    with z.open("3D/3dmodel.model", "w", force_zip64=True) as f:
        f.write(b'<?xml version="1.0"?><model unit="millimeter" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02"><resources><object id="1" type="model"><mesh><vertices>')
        for _ in range(200):
            f.write(b" " * (1 << 20))
        f.write(b'<vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/><vertex x="0" y="1" z="0"/></vertices><triangles><triangle v1="0" v2="1" v3="2"/></triangles></mesh></object></resources><build><item objectid="1"/></build></model>')
PYEOF
  c=$(code -H "X-Api-Key: $RW" -F "file=@$tmp/bomb.3mf" "$U/api/jobs")
  [ "$c" = 201 ] || fail "9: bomb upload: $c $(cat "$tmp/r")"
  id=$(sed -n 's/.*"id":\([0-9]*\).*/\1/p' "$tmp/r")
  for _ in $(seq 200); do
    curl -s -H "X-Api-Key: $RW" "$U/api/jobs/$id" > "$tmp/j"
    grep -q '"state":"failed"' "$tmp/j" && break
    sleep 0.1
  done
  grep -q 'unpacks to more than' "$tmp/j" || fail "9: bomb job: $(cat "$tmp/j")"
  hwm=$(sed -n 's/^VmHWM:\s*//p' /proc/$pid/status)
  row 9 "POST a 3MF bomb ($(stat -c %s "$tmp/bomb.3mf") B, 200 MiB of XML)" "201, job failed: unpacks to more than 16777216 bytes; daemon VmHWM $hwm"
fi

# 7: 10^5 copies of one face load at once; a 10^5-face fan is cancelled mid-prepare and SIGTERM is prompt
{ printf 'v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 2 4\nf 2 3 4\nf 3 1 4\n'; yes 'f 1 2 3' | head -n 100000; } > "$tmp/dups.obj"
c=$(code -H "X-Api-Key: $RW" -F "file=@$tmp/dups.obj" -F 'options={"method": "none"}' "$U/api/jobs")
id=$(sed -n 's/.*"id":\([0-9]*\).*/\1/p' "$tmp/r")
for _ in $(seq 300); do
  curl -s -H "X-Api-Key: $RW" "$U/api/jobs/$id" > "$tmp/j"
  grep -q '"state":"preparing"\|"state":"queued"' "$tmp/j" || break
  sleep 0.1
done
grep -q '"state":"preparing"\|"state":"queued"' "$tmp/j" && fail "7: dups still preparing after 30 s"
row 7 "POST an OBJ of 10^5 copies of 'f 1 2 3' (800 KB)" "$c; prepared: $(sed -n 's/.*"state":"\([a-z-]*\)".*"reason":"\([^"]*\)".*/\1 \2/p' "$tmp/j" | head -n 1)"

# 12: Last-Event-ID above the newest event
timeout 3 curl -s -N -H "X-Api-Key: $RO" -H "Last-Event-ID: 999999" "$U/api/events" > "$tmp/sse" 2>/dev/null
grep -q "^event: reset" "$tmp/sse" && grep -q "^event: job-add" "$tmp/sse" || fail "12: $(head -c 300 "$tmp/sse")"
row 12 "GET /api/events, Last-Event-ID: 999999" "event: reset, then the log from id 1"

# 13: SIGHUP applies upload_max and closes a revoked key's stream
curl -s -N -H "X-Api-Key: $RO" "$U/api/events" > "$tmp/sse2" 2>&1 &
spid=$!
sleep 0.5
config 1 0
kill -HUP $pid
for _ in $(seq 100); do grep -q "reloaded" "$tmp/log" && break; sleep 0.05; done
for _ in $(seq 100); do kill -0 $spid 2>/dev/null || break; sleep 0.05; done
kill -0 $spid 2>/dev/null && { kill $spid; fail "13: revoked key's stream still open"; }
wait $spid 2>/dev/null
row 13 "SIGHUP dropping the read-only key: its open event stream" "closed by the daemon"
c=$(code -H "X-Api-Key: $RW" -F "file=@$tmp/big2.stl" "$U/api/jobs")
[ "$c" = 413 ] || fail "13: upload over the reloaded upload_max: $c"
row 13 "SIGHUP upload_max_mb 2 -> 1, then a 1.5 MB upload" "$c $(err)"

# 10: tmp-* of a killed daemon are gone after a restart
kill -9 $pid; wait $pid 2>/dev/null; pid=
echo half > "$tmp/data/files/tmp-AbC123"
config 8 0
start
[ -e "$tmp/data/files/tmp-AbC123" ] && fail "10: tmp file survived the restart"
row 10 "kill -9, files/tmp-AbC123 left, restart" "removed at start"

# 7: a job cancelled while it prepares a 10^5-face fan (every face on one
# edge) stops, and SIGTERM right after it does not wait on the worker
awk 'BEGIN { print "v 0 0 0"; print "v 20 0 0"; n = 100000;
  for (i = 0; i < n; i++) printf "v 10 %.6f %.6f\n", 20 * cos(3.14159 * i / n), 20 * sin(3.14159 * i / n);
  for (i = 0; i < n; i++) printf "f 1 2 %d\n", i + 3 }' > "$tmp/fan.obj"
c=$(code -H "X-Api-Key: $RW" -F "file=@$tmp/fan.obj" -F 'options={"method": "slim"}' "$U/api/jobs")
id=$(sed -n 's/.*"id":\([0-9]*\).*/\1/p' "$tmp/r")
for _ in $(seq 200); do
  curl -s -H "X-Api-Key: $RW" "$U/api/jobs/$id" | grep -q '"state":"preparing"' && break
  sleep 0.05
done
c=$(code -X POST -H "X-Api-Key: $RW" "$U/api/jobs/$id/cancel")
[ "$c" = 200 ] || fail "7: cancel while preparing: $c $(cat "$tmp/r")"
t0=$(date +%s%N)
kill -TERM $pid
for _ in $(seq 200); do kill -0 $pid 2>/dev/null || break; sleep 0.05; done
kill -0 $pid 2>/dev/null && fail "SIGTERM: still running after 10 s"
row 7 "cancel a 10^5-face fan (slim) mid-prepare, then SIGTERM" "cancel $c; daemon exited $(( ($(date +%s%N) - t0) / 1000000 )) ms after SIGTERM"
wait $pid; rc=$?; pid=
[ $rc = 0 ] || fail "SIGTERM: exit $rc"
echo "farmd_harden: ok"
