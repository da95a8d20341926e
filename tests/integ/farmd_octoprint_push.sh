#!/usr/bin/env bash
# tests/integ/farmd_octoprint_push.sh - slimfarmd's OctoPrint push socket
# (issue 35) as OctoPrint clients written by others use it: FDM Monster's
# raw websocket session and the web UI's SockJS one
# (tests/replay/farmd/octoprint-fdmmonster-socket.txt) replayed by
# tests/replay/replay.py with the standard-library websocket client
# tests/replay/wsclient.py against a daemon with one simulated Marlin
# printer over real loopback: the auth by POST /api/login's session,
# `history` and `current` shapes, the print events of a job that ends and
# one that is cancelled.  Then the session's end closes the socket: a
# reload that removes the key (SIGHUP) ends its login sessions, and the
# socket gets reauthRequired "logout" and is closed; so does one whose key a
# reload turns metrics-only.  Guessed sessions count as failed logins of
# the address, with its REST ones: past the burst the socket is closed
# (1013) and the address's keyed requests get 429.  Every wait has a
# generous bound (a loaded machine).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
t0=$(date +%s)
dir=$(dirname "$0")/../replay
start_sim mk --speed 20
cp -r config/printers config/materials "$tmp/"
KEY2=other-key-0123456789abcdef
write_ini() {
  {
    printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$1"
    printf '[printer mk]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' "$(cat "$tmp/mk.addr")"
    printf 'auto_eject: true\ngcode_models: *\n'
  } > "$tmp/farm.ini"
}
write_ini "$RW, $KEY2"
start_daemon
/usr/bin/python3 "$dir/replay.py" "$SLIMFARM_URL" "$RW" "$dir/farmd/octoprint-fdmmonster-socket.txt" ||
  fail "FDM Monster's socket session: slimfarmd does not push as the client expects"
# a socket of KEY2's; a reload that removes KEY2 ends its session and the socket
write_ini "$RW"
cp "$tmp/farm.ini" "$tmp/farm-rw.ini"
write_ini "$RW, $KEY2"
export DAEMON_PID=$pid INI=$tmp/farm.ini
cat > "$tmp/logout.txt" <<'EOS'
POST /api/login?passive=true json={} -> 200 name>USER session>SESSION
WS OPEN /sockjs/websocket -> 101
WS NEXT connected.version:str
WS SEND '{"auth":"{USER}:{SESSION}"}'
WS NEXT history.state.text:str
WS RECV current.state.text:str
RUN 'cp "$INI" "$INI.old" && cp "${INI%.ini}-rw.ini" "$INI" && kill -HUP "$DAEMON_PID"'
WS RECV 60 reauthRequired.reason=logout
WS CLOSED 30 code=1008
EOS
/usr/bin/python3 "$dir/replay.py" "$SLIMFARM_URL" "$KEY2" "$tmp/logout.txt" ||
  fail "a removed key's login session does not end its socket"
# a socket counts with its key's event streams: past HTTP_STREAMS_PER_KEY (16) its auth is
# refused (reauthRequired, close 1013: try again later) and the streams are untouched
/usr/bin/python3 - "$dir" "$SLIMFARM_URL" "$RW" <<'EOP' || fail "a socket past the key's 16 streams is not refused"
import json, socket, sys, time, urllib.parse, urllib.request
sys.path.insert(0, sys.argv[1])
import wsclient
url, key = sys.argv[2], sys.argv[3]
u = urllib.parse.urlparse(url)
streams = []
for i in range(16):
    s = socket.create_connection((u.hostname, u.port), 30)
    s.sendall(("GET /api/events HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\n\r\n" % key).encode())
    s.settimeout(30)
    assert s.recv(64).startswith(b"HTTP/1.1 200"), "stream %d refused" % i
    streams.append(s)
req = urllib.request.Request(url + "/api/login", data=b'{"passive":true}', method="POST",
                             headers={"X-Api-Key": key, "Content-Type": "application/json"})
login = json.load(urllib.request.urlopen(req, timeout=30))
ws = wsclient.Ws(url, "/sockjs/websocket")
assert "connected" in json.loads(ws.recv(30))
ws.send(json.dumps({"auth": "%s:%s" % (login["name"], login["session"])}))
msg = json.loads(ws.recv(30))
assert msg == {"reauthRequired": {"reason": "stale"}}, msg
assert ws.recv(30) is None and ws.close_code == 1013, ws.close_code
streams.pop().close()  # one stream fewer: a socket fits again
end = time.monotonic() + 30
while True:
    ws = wsclient.Ws(url, "/sockjs/websocket")
    ws.recv(30)
    ws.send(json.dumps({"auth": "%s:%s" % (login["name"], login["session"])}))
    msg = json.loads(ws.recv(30))
    if "history" in msg:
        break
    assert time.monotonic() < end, msg  # the closed stream is counted until the server sees it go
    time.sleep(0.2)
print("16 streams, then a socket refused; with 15 it stands")
EOP
grep -q "ended 1 OctoPrint login sessions of revoked API keys" "$tmp/log" ||
  fail "the reload did not log the session it ended"
# a key that a reload turns metrics-only ends its sockets as a removed key does (found by
# review: a metrics key may read /metrics alone)
write_ini "$RW, $KEY2"
sed "s/^api_keys: .*/api_keys: $RW\nmetrics_keys: $KEY2/" "$tmp/farm.ini" > "$tmp/farm-metrics.ini"
kill -HUP $pid
wait_for 60 sh -c "curl -sf -H 'X-Api-Key: $KEY2' '$SLIMFARM_URL/api/printers' > /dev/null" ||
  fail "the reload did not bring KEY2 back"
sed 's/-rw.ini/-metrics.ini/' "$tmp/logout.txt" > "$tmp/metrics.txt"
/usr/bin/python3 "$dir/replay.py" "$SLIMFARM_URL" "$KEY2" "$tmp/metrics.txt" ||
  fail "a key turned metrics-only keeps its socket"
# guessing sessions on a socket counts as failed logins of the address, with its REST
# ones (review finding): past the burst the socket is closed (1013: try again later),
# and a good key's REST request from that address is answered 429 (last: it slows this
# address for up to a minute)
/usr/bin/python3 - "$dir" "$SLIMFARM_URL" "$RW" <<'EOP' || fail "guessed push socket sessions are not slowed"
import json, sys, time, urllib.error, urllib.request
sys.path.insert(0, sys.argv[1])
import wsclient
url, key = sys.argv[2], sys.argv[3]
ws = wsclient.Ws(url, "/sockjs/websocket")
assert "connected" in json.loads(ws.recv(30))
guesses, end = 0, time.monotonic() + 60
while True:  # each guess answered "stale"; the last ones' answer is followed by the close
    try:
        ws.send(json.dumps({"auth": "key 0:guess-%d" % guesses}))
    except OSError:
        break
    guesses += 1
    msg = ws.recv(30)
    if msg is None:
        break
    assert json.loads(msg) == {"reauthRequired": {"reason": "stale"}}, msg
    assert guesses < 5000 and time.monotonic() < end, "%d guesses, the socket still open" % guesses
assert ws.close_code == 1013, ws.close_code
req = urllib.request.Request(url + "/api/printers", headers={"X-Api-Key": key})
try:
    urllib.request.urlopen(req, timeout=30)
    assert False, "a good key's request after the guesses was answered"
except urllib.error.HTTPError as e:
    assert e.code == 429, e.code
print("socket closed (1013) after %d guessed sessions; REST from the address: 429" % guesses)
EOP
# a clean stop (ASan: nothing leaks, nothing is used after free)
kill -TERM $pid; wait $pid; rc=$?; pid=
if [ $rc -ne 0 ] || grep -q "LeakSanitizer\|AddressSanitizer" "$tmp/log"; then
  fail "slimfarmd exited $rc on SIGTERM, or the sanitizers reported"
fi
echo "farmd_octoprint_push: ok in $(( $(date +%s) - t0 )) s"
