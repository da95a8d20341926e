#!/usr/bin/env bash
# tests/integ/farmd_policy.sh - the G-code policy (drivers/gpolicy.h) at
# the farm's door, through the REST API: uploads to POST /api/files/local
# (OctoPrint's route, as PrusaSlicer sends them) and to Moonraker's
# /server/files/upload, with a simulated Marlin printer (unattended, the
# default) and a simulated Klipper printer (Moonraker, attended).  Refused
# with a 400 naming the line, leaving no job and no stored file: M110 in
# the middle of a file and as its first line, M118 "Resend: 1", NUL and
# control bytes, non-ASCII outside a comment, M502, M500, M997, M0, M600,
# M112, SAVE_CONFIG; a file with 25 refused lines names 20, then "and 5
# more".  M600 is refused while the Marlin printer is unattended, and
# accepted once farm.ini allows it there (allow_gcode: M600, SIGHUP): an
# upload must pass every printer that may take it.  A clean file prints.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
PY=/usr/bin/python3

start_sim mk3 --speed 3000
start_net voron moonraker --speed 2000 --api-key voron-key
cp -r config/printers config/materials "$tmp/"
write_config() { # ALLOW: mk3's allow_gcode
  {
    printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
    printf '[printer mk3]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' "$(cat "$tmp/mk3.addr")"
    printf 'auto_eject: true\ngcode_models: *\nallow_gcode: %s\n' "$1"
    printf '[printer voron]\ndriver: moonraker\nurl: %s\napi_key: voron-key\n' "$(cat "$tmp/voron.addr")"
    printf 'material: PLA\nauto_eject: true\ngcode_models: *\nattended: true\n'
  } > "$tmp/farm.ini"
}
write_config ""
start_daemon
wait_for 60 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 2 ]" || fail "printers: $("$C" printers)"

run_py() { # PHASE
  PORT=$http_port RW=$RW TMP=$tmp PHASE=$1 $PY - "$(dirname "$0")/lib" <<'PY'
import glob, json, os, sys, time
sys.path.insert(0, sys.argv[1])
from slicers import *
port, rw, tmp, phase = int(os.environ["PORT"]), os.environ["RW"], os.environ["TMP"], os.environ["PHASE"]

def check(cond, what):
    if not cond:
        sys.exit("FAIL: " + what)

def files():
    return sorted(os.path.basename(f) for f in
                  glob.glob(os.path.join(tmp, "data", "files", "**"), recursive=True) if os.path.isfile(f))

def jobs():
    st, h, b = curl_get(port, "/api/jobs", "test", rw)
    check(st == 200, "jobs: %d" % st)
    return json.loads(b)["jobs"]

def body(head=b"", mid=b"", tail=b""):
    g = head + b"G90\nM83\nG28\n"
    for i in range(10):
        g += b"G1 X%d Y%d F6000\nG1 X%d Y%d E0.5 F1800\n" % (10 + i, 10 + i, 20 + i, 20 + i)
        if i == 4:
            g += mid
    return g + b"M84\n" + tail

def post(data, want, route):
    st, h, b = route(port, rw, "bad.gcode", data)
    check(st == 400, "%s: want 400, got %d %s" % (want, st, b[:300]))
    err = json.loads(b)["error"]
    for w in want if isinstance(want, list) else [want]:
        check(w in err, "%r not in %r" % (w, err))
    return err

def refused(cases):
    """Each (data, want[, route]) is a 400 naming want; together they leave no file, no job.
    In parallel, each answered once its check is done."""
    from concurrent.futures import ThreadPoolExecutor
    before_files, before_jobs = files(), len(jobs())
    with ThreadPoolExecutor(len(cases)) as ex:
        errs = list(ex.map(lambda c: post(c[0], c[1], c[2] if len(c) > 2 else prusaslicer), cases))
    check(files() == before_files, "a refused upload left a file: %r" % files())
    check(len(jobs()) == before_jobs, "a refused upload added a job")
    return errs

if phase == "refuse":
    # body(): line 1 G90 ... lines 4..13 moves; mid lands after line 13
    cases = [(body(mid=b"M110 N0\n"), "G-code 'bad.gcode': line 14: M110: the host numbers the lines"),
             (b"M110 N0\n" + body(), "line 1: M110"),
             (body(mid=b"M118 Resend: 1\n"), "line 14: M118: prints its text raw"),
             (body(mid=b"G1 X1\x00 Y2\n"), "line 14: byte 0x00: control bytes"),
             (body(mid=b"G1 X1\x1b\n"), "line 14: byte 0x1b"),
             (body(mid=b"M117 \xc2\xb0\n"), "line 14: byte 0xc2: non-ASCII"),
             (body(mid=b"M0\n" * 25), ["line 14: M0", "line 33: M0", "; and 5 more"]),
             # Moonraker's route: the same policy
             (body(mid=b"M600\n"), "line 14: M600: a filament change waits for a person", moonraker)]
    for cmd in (b"M502", b"M500", b"M997", b"M0", b"M600", b"M112", b"SAVE_CONFIG"):
        cases.append((body(mid=cmd + b"\n"), "line 14: %s: " % cmd.decode()))
    errs = refused(cases)
    check("line 34:" not in errs[6], "more than 20 lines named: %r" % errs[6])
    # comments may hold anything printable, and M117 text that is no reply passes
    st, h, b = prusaslicer(port, rw, "ok.gcode", body(mid=b"M117 Layer 5 ; M110 N0 \xc2\xb0C\n"))
    check(st == 201, "clean upload: %d %s" % (st, b[:300]))
    jid = json.loads(b)["slimfarm"]["job_id"]
    end = time.time() + 120
    while time.time() < end:
        st, h, b = curl_get(port, "/api/jobs/%d" % jid, "test", rw)
        if json.loads(b)["job"]["state"] == "done":
            break
        time.sleep(0.2)
    check(json.loads(b)["job"]["state"] == "done", "clean job: %s" % b[:300])
else:
    # mk3 allows M600 now, voron is attended: both take it
    st, h, b = moonraker(port, rw, "change.gcode", body(mid=b"M600\n"))
    check(st == 201, "M600 with allow_gcode and attended: %d %s" % (st, b[:300]))
    # M0: voron attended, but mk3 allows only M600
    refused([(body(mid=b"M0\n"), "line 14: M0: waits for a person")])
print("policy %s: ok" % phase)
PY
}
run_py refuse || fail "policy refusals"
write_config "M600"
kill -HUP "$pid"
wait_for 30 grep -q "reloaded " "$tmp/log" || fail "no reload"
run_py allow || fail "policy allow"
echo "farmd_policy: ok"
