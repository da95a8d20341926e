#!/usr/bin/env bash
# tests/integ/farmd_notify.sh - the daemon tells the operator: a real
# slimfarmd printing on a simulated Marlin (no ejector) posts a webhook for
# the job done and for the bed that needs clearing to a loopback listener
# (which answers the first request 500: the daemon tries it again), mails
# a failed job through a loopback SMTP sink (aiosmtpd), and tells a
# Slack-style listener when the queue runs empty.  Also: the
# [notify] section's options are checked with messages naming the field,
# and neither the token nor the webhook's url reaches the log.  Every wait
# polls for its condition.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
SINKS=$(dirname "$0")/lib/sinks.py
/usr/bin/python3 -c 'import aiosmtpd' 2>/dev/null || { echo "SKIP: python3-aiosmtpd missing (make deps)"; exit 77; }

mkdir -p "$tmp/sink" "$tmp/chat"
/usr/bin/python3 "$SINKS" http "$tmp/sink" & sims+=($!)
/usr/bin/python3 "$SINKS" smtp "$tmp/sink" & sims+=($!)
/usr/bin/python3 "$SINKS" http "$tmp/chat" & sims+=($!)
wait_for 30 test -s "$tmp/sink/http.port" -a -s "$tmp/sink/smtp.port" -a -s "$tmp/chat/http.port" \
  || fail "sinks did not start"
hport=$(cat "$tmp/sink/http.port") sport=$(cat "$tmp/sink/smtp.port") cport=$(cat "$tmp/chat/http.port")

# Bad sections are refused, naming the field.
bad() { # EXPECTED LINES...
  local want=$1; shift
  printf '[farm]\ndata_dir: %s/bad\n[notify x]\n' "$tmp" > "$tmp/bad.ini"
  printf '%s\n' "$@" >> "$tmp/bad.ini"
  out=$("$D" -c "$tmp/bad.ini" --check 2>&1) && fail "accepted: $*"
  [[ "$out" == *"$want"* ]] || fail "message for $*: $out"
}
bad "bad.ini:3: section 'notify x': option 'url' is required" "events: all"
bad "bad.ini:5: section 'notify x': option 'events': 'job-dne' is not one of" "url: http://h/x" "events: job-dne"
bad "option 'url': it does not start with http://, https://, smtp:// or smtps://" "url: ftp://h/x"
bad "section 'notify x': option 'to': a mail target needs at least one recipient" "url: smtp://h" "from: a@b"
bad "option 'retries': '99' is not a whole number in 0..10" "url: http://h/x" "retries: 99"
bad "option 'colour' is not valid in section 'notify x'" "url: http://h/x" "colour: red"

start_sim mk3 --speed 3000
TOKEN=tok-secret-0123456789
one_printer_ini mk3 false
cat >> "$tmp/farm.ini" <<INI
[notify hook]
url: http://127.0.0.1:$hport/hook/secret-path
events: job-done, bed-clear
token: $TOKEN
[notify mail]
url: smtp://127.0.0.1:$sport
from: farm@example.org
to: ops@example.org, night@example.org
events: job-failed
[notify chat]
url: http://127.0.0.1:$cport/chat
format: slack
events: queue-empty
INI
start_daemon
wait_for 60 sh -c "'$C' printers | grep -q ' idle '" || fail "printer: $("$C" printers)"

tetra "$tmp/t.stl" 10
id=$(submit "$tmp/t.stl" --method none)
wait_for 300 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$id | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"job\"][\"state\"])')\" = done ]" \
  || fail "job $id did not finish"

# The webhook got both events with 200, the first request answered 500
# was tried again, and the JSON says what happened.
check_hook() {
  /usr/bin/python3 - "$tmp/sink/http.log" "$id" "$TOKEN" <<'PY'
import json, sys
log, job, token = sys.argv[1], int(sys.argv[2]), sys.argv[3]
reqs = [json.loads(l) for l in open(log)]
ok = {}
for r in reqs:
    assert r["path"] == "/hook/secret-path", r
    assert r["headers"].get("Authorization") == "Bearer " + token, r["headers"]
    assert r["headers"].get("Content-Type") == "application/json", r["headers"]
    b = json.loads(r["body"])
    if r["status"] == 200:
        ok[b["event"]] = b
failed = [json.loads(r["body"])["event_id"] for r in reqs if r["status"] == 500]
assert len(failed) == 1, reqs
assert failed[0] in [b["event_id"] for b in ok.values()], ("not retried", reqs)
d = ok["job-done"]
assert d["job"]["id"] == job and d["job"]["name"] == "t.stl" and d["job"]["state"] == "done", d
assert d["job"]["copies_done"] == 1 and d["printer"] == "mk3", d
assert d["text"] == "job #%d t.stl done on mk3 (1 of 1 copies)" % job, d
c = ok["bed-clear"]
assert c["printer"] == "mk3" and c["text"] == "printer mk3 needs its bed cleared", c
assert set(ok) == {"job-done", "bed-clear"}, ok  # events: filters the rest
PY
}
wait_for 60 check_hook 2>/dev/null || { check_hook; fail "webhook: $(cat "$tmp/sink/http.log")"; }
grep -q "hook: .* attempt 1 failed (status 500); again in 1000 ms" "$tmp/log" || fail "no retry logged"

# A job that fails (its part holds no facets) is mailed to both recipients.
printf 'solid empty\nendsolid empty\n' > "$tmp/empty.stl"
fid=$(submit "$tmp/empty.stl" --method none)
check_mail() {
  /usr/bin/python3 - "$tmp/sink/smtp.log" "$fid" <<'PY'
import json, sys
mails = [json.loads(l) for l in open(sys.argv[1])]
fid = int(sys.argv[2])
assert len(mails) == 1, mails
m = mails[0]
assert m["from"] == "farm@example.org", m
assert sorted(m["to"]) == ["night@example.org", "ops@example.org"], m
assert ("Subject: [slimfarm] job #%d empty.stl failed" % fid) in m["data"], m["data"]
assert "event: job-failed" in m["data"], m["data"]
PY
}
wait_for 120 check_mail 2>/dev/null || { check_mail; fail "mail: $(cat "$tmp/sink/smtp.log" 2>/dev/null)"; }

# The queue ran empty (when the job started, and after the failed one):
# a Slack-style body, its first attempt answered 500 and tried again.
check_chat() {
  /usr/bin/python3 - "$tmp/chat/http.log" <<'PY'
import json, sys
reqs = [json.loads(l) for l in open(sys.argv[1])]
assert reqs[0]["status"] == 500, reqs
ok = [json.loads(r["body"]) for r in reqs if r["status"] == 200]
assert ok and all(b == {"text": "slimfarm: the queue is empty: no job waits for a printer"}
                  for b in ok), reqs
PY
}
wait_for 60 check_chat 2>/dev/null || { check_chat; fail "chat: $(cat "$tmp/chat/http.log" 2>/dev/null)"; }

# Secrets stay out of the log; a reload keeps the targets.
grep -q "$TOKEN\|secret-path" "$tmp/log" && fail "a secret reached the log"
kill -HUP "$pid"
wait_for 30 grep -q "reloaded .*, 3 notify targets" "$tmp/log" || fail "reload"
echo "farmd_notify: ok"
