#!/usr/bin/env bash
# tests/integ/farmd_upload.sh - slicers send jobs to the farm: the exact
# requests PrusaSlicer, OrcaSlicer and Cura's OctoPrint plugin send to an
# OctoPrint host, and a Moonraker client's upload, replayed byte for byte
# (tests/integ/lib/slicers.py) against slimfarmd over loopback, with two
# simulated Marlin printers: every upload is queued and printed as is (each
# printer's executed log equals the uploaded G-code), a busy farm queues
# (never 409).  Bad uploads (no file part, a bad G-code line, G-code no
# printer can run, too large, wrong key, read-only key, metrics key) get
# clear errors and leave no job and no stored file.  /metrics passes a
# strict parser of the Prometheus text format and its counters move as
# jobs print.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
PY=/usr/bin/python3
RO=ro-key-0123456789abcdef
MK=metrics-key-0123456789ab

start_sim mk3 --speed 3000
start_sim ender --speed 3000 --tcp 0
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf 'api_keys_readonly: %s\nmetrics_keys: %s\nupload_max_mb: 1\n' "$RO" "$MK"
  printf '[printer mk3]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' "$(cat "$tmp/mk3.addr")"
  printf 'bed_size: 250, 210, 210\nauto_eject: true\ngcode_models: MK3S, MK3SMMU2S\n'
  printf '[printer ender]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' "$(cat "$tmp/ender.addr")"
  printf 'auto_eject: true\ngcode_models: *\n'
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 2 ]" || fail "printers: $("$C" printers)"

PORT=$http_port RW=$RW RO=$RO MK=$MK TMP=$tmp $PY - "$(dirname "$0")/lib" <<'PY' || fail "slicer replays"
import glob, hashlib, json, os, sys, time
sys.path.insert(0, sys.argv[1])
from slicers import *
port, rw, ro, mk, tmp = int(os.environ["PORT"]), os.environ["RW"], os.environ["RO"], os.environ["MK"], os.environ["TMP"]
# a store host (PostgreSQL) labels its printers' series with its host too, a single host not
own = {"host": os.environ["DAEMON_HOST"]} if os.environ.get("DAEMON_HOST") else {}

def body(moves, tail="", head=""):
    g = head + "G90\nM83\nG28\n"
    for i in range(moves):
        g += "G1 X%d Y%d F6000\nG1 X%d Y%d E0.5 F1800\n" % (10 + i, 10 + i, 20 + i, 20 + i)
    return (g + "M84\n" + tail).encode()

prusa_tail = ("; filament used [mm] = 412.50\n; filament used [g] = 1.23\n"
              "; prusaslicer_config = begin\n; filament_type = PLA\n; gcode_flavor = marlin2\n"
              "; nozzle_diameter = 0.4\n; printer_model = MK3S\n; prusaslicer_config = end\n")
orca_tail = ("; filament used [g] = 2.50\n; CONFIG_BLOCK_START\n; filament_type = PLA\n"
             "; nozzle_diameter = 0.4\n; printer_model = MK3S\n; CONFIG_BLOCK_END\n")
cura_head = (";FLAVOR:Marlin\n;TIME:60\n;Filament used: 0.4m\n;Layer height: 0.2\n"
             ";Generated with Cura_SteamEngine 5.8.1\n")

def check(cond, what):
    if not cond:
        sys.exit("FAIL: " + what)

def api(path, key=rw):
    st, h, b = curl_get(port, path, "test", key)
    check(st == 200, "GET %s: %d %s" % (path, st, b[:200]))
    return json.loads(b)

def files():
    """Stored files by name (their SHA-256) and temporaries, anywhere under files/."""
    return [os.path.basename(f) for f in glob.glob(os.path.join(tmp, "data", "files", "**"), recursive=True)
            if os.path.isfile(f)]

def metrics(key=ro):
    st, h, b = curl_get(port, "/metrics", "Prometheus/2.45.0", key)
    check(st == 200, "metrics: %d %s" % (st, b[:200]))
    check(h.get("content-type", "").startswith("text/plain; version=0.0.4"), "metrics type %r" % h)
    return parse_prom(b.decode())[0]

m0 = metrics()
check(metric(m0, "slimfarm_printers", state="idle") == 2, "two idle printers in /metrics")
check(metric(m0, "slimfarm_prints_total", printer="mk3", outcome="done", **own) == 0, "no prints yet")
jobs = []

# PrusaSlicer: test, then upload with print=true; a long job so the farm is busy
st, h, b = prusaslicer(port, rw, "box_0.2mm_PLA_MK3S_1h.gcode", body(400, prusa_tail))
check(st == 201, "prusaslicer upload: %d %s" % (st, b[:300]))
r = json.loads(b)
check(r["files"]["local"]["origin"] == "local" and r["done"] and r["effectivePrint"], "octoprint body %r" % r)
check("/api/files/local/job-" in h.get("location", ""), "Location %r" % h)
jobs.append(r["slimfarm"]["job_id"])
# OrcaSlicer with print=false: queued all the same (documented), both while mk3 is busy
cube = body(20, orca_tail)
st, h, b = orcaslicer(port, rw, "cube.gcode", cube, print_=False)
check(st == 201, "orca upload while busy: %d %s" % (st, b[:300]))
jobs.append(json.loads(b)["slimfarm"]["job_id"])
# Cura printing at once (select and print in the upload), and Cura selecting after Location
st, h, b, sel = cura(port, rw, "CE3_part.gcode", body(30, "", cura_head), auto_print=True)
check(st == 201 and sel is None, "cura upload: %d %s" % (st, b[:300]))
jobs.append(json.loads(b)["slimfarm"]["job_id"])
st, h, b, sel = cura(port, rw, "CE3_other.gcode", body(25, "", cura_head), auto_print=False)
check(st == 201 and sel is not None and sel[0] == 204, "cura select after Location: %r" % (sel,))
jobs.append(json.loads(b)["slimfarm"]["job_id"])
# Moonraker upload
st, h, b = moonraker(port, rw, "klipper_part.gcode", body(15, prusa_tail))
check(st == 201, "moonraker upload: %d %s" % (st, b[:300]))
res = json.loads(b)["result"]
check(res["print_queued"] and not res["print_started"] and res["item"]["root"] == "gcodes", "moonraker body %r" % res)
jobs.append(int(res["item"]["path"].split("/")[0][4:]))
st, h, b = request(port, ("POST /printer/print/start?filename=%s HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\n"
                          "Content-Length: 0\r\n\r\n" % (res["item"]["path"], rw)).encode())
check(st == 200 and json.loads(b)["result"] == "ok", "print start: %d %s" % (st, b))
# a mesh uploaded through the OctoPrint route goes through the pipeline
stl = b"solid t\n" + b"".join(b"facet normal 0 0 0\nouter loop\nvertex %s\nvertex %s\nvertex %s\nendloop\nendfacet\n" % t for t in [
    (b"0 0 0", b"0 8 0", b"8 0 0"), (b"0 0 0", b"8 0 0", b"0 0 8"), (b"0 0 0", b"0 0 8", b"0 8 0"), (b"8 0 0", b"0 8 0", b"0 0 8")]) + b"endsolid t\n"
st, h, b = prusaslicer(port, rw, "tetra.stl", stl)
check(st == 201, "mesh upload: %d %s" % (st, b[:300]))
jobs.append(json.loads(b)["slimfarm"]["job_id"])

by_id = {j["id"]: j for j in api("/api/jobs")["jobs"]}
check(all(by_id[j]["state"] in ("queued", "preparing", "ready", "printing", "done") for j in jobs), "states %r" % by_id)
check(by_id[jobs[0]]["material"] == "PLA", "material from filament_type")
check(by_id[jobs[5]]["method"] != "gcode", "the mesh is prepared")

# bad uploads: clear errors, nothing added
n_jobs = len(by_id)
sent = []  # every refused file's bytes: none may be stored
def refused(res, code, words, what, data=None):
    if data is not None:
        sent.append(hashlib.sha256(data).hexdigest())
    st, h, b = res[:3]
    check(st == code, "%s: %d, want %d: %s" % (what, st, code, b[:300]))
    msg = json.loads(b)["error"]
    for w in words:
        check(w in msg, "%s: %r lacks %r" % (what, msg, w))
refused(curl_mime(port, "/api/files/local", "PrusaSlicer/2.9.4", rw, [("print", "true"), ("path", "")], None, b""),
        400, ["'file'"], "no file part")
bad = body(3) + b"G1 X" + b"1" * 300 + b"\n" + prusa_tail.encode()
refused(prusaslicer(port, rw, "bad.gcode", bad), 400, ["G-code 'bad.gcode':11: command too long"],
        "a bad G-code line", bad)
xl = body(3, prusa_tail.replace("MK3S", "XL").replace("= 0.4", "= 0.6"))
refused(prusaslicer(port, rw, "xl.gcode", xl), 400,
        ["'XL'", "no printer could run it", "mk3: G-code for 'XL'", "ender: G-code for a 0.6 mm nozzle"],
        "G-code no printer can run", xl)
refused(prusaslicer(port, rw, "big.gcode", body(3) + b"; " + b"x" * (1100 << 10) + b"\n"),
        413, ["limit"], "an upload over upload_max")
refused(prusaslicer(port, "wrong-key-0123456789abcdef", "a.gcode", body(3, prusa_tail)), 401, ["key"], "wrong key")
ro_file = body(4, prusa_tail)
refused(curl_mime(port, "/api/files/local", "PrusaSlicer/2.9.4", ro, [("print", "true")], "a.gcode", ro_file),
        403, ["read-only"], "read-only key", ro_file)
refused(curl_mime(port, "/api/files/local", "PrusaSlicer/2.9.4", mk, [("print", "true")], "a.gcode", body(3, prusa_tail)),
        403, ["metrics"], "metrics key uploading")
refused(curl_get(port, "/api/jobs", "x", mk), 403, ["metrics"], "metrics key on the API")
st, h, b = curl_get(port, "/metrics", "Prometheus/2.45.0", "nope-0123456789abcdefgh")
check(st == 401, "metrics without a valid key: %d" % st)
st, h, b = request(port, ("GET /metrics HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer %s\r\n\r\n" % mk).encode())
check(st == 200, "metrics key as a bearer token: %d" % st)
stored = files()
check(len(api("/api/jobs")["jobs"]) == n_jobs, "a refused upload added a job")
check(not [f for f in stored if f.startswith("tmp-")], "a temporary file was left: %r" % stored)
check(not [h for h in sent if h in stored], "a refused upload was stored")
check(hashlib.sha256(cube).hexdigest() in stored, "the check sees stored uploads")
st, h, b = request(port, ("POST /api/files/local/job-999/x.gcode HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\n"
                          "Content-Type: application/json\r\nContent-Length: 20\r\n\r\n{\"command\":\"select\"}" % rw).encode())
check(st == 404, "select of an unknown upload: %d" % st)

# every upload prints; the counters move
end = time.time() + 300
while time.time() < end:
    states = {j["id"]: j["state"] for j in api("/api/jobs")["jobs"]}
    if all(states[j] == "done" for j in jobs):
        break
    time.sleep(0.5)
check(all(states[j] == "done" for j in jobs), "jobs not done: %r" % states)
# a select that arrives after the printer finished the upload is answered as done
st, h, b = request(port, ("POST /api/files/local/job-%d/x.gcode HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\n"
                          "Content-Type: application/json\r\nContent-Length: 20\r\n\r\n{\"command\":\"select\"}" % (jobs[0], rw)).encode())
check(st == 204, "select of an upload already printed: %d %s" % (st, b[:200]))
m1 = metrics()
done = sum(metric(m1, "slimfarm_prints_total", printer=p, outcome="done", **own) for p in ("mk3", "ender"))
check(done == len(jobs), "prints_total done %s, want %d" % (done, len(jobs)))
check(metric(m1, "slimfarm_jobs", state="done") == len(jobs), "jobs done in metrics")
# the estimates of the files that state grams: 1.23 (PrusaSlicer) + 2.50 (Orca) + 1.23 (Moonraker)
grams = sum(metric(m1, "slimfarm_filament_used_grams_total", printer=p, **own) for p in ("mk3", "ender"))
check(grams >= 1.23 + 2.50 + 1.23 - 1e-6, "filament grams %s" % grams)
check(metric(m1, "slimfarm_queue_wait_seconds_count") >= 1, "queue wait observed")
check(metric(m1, "slimfarm_stage_duration_seconds_count", stage="print") == len(jobs), "print durations")
check(metric(m1, "slimfarm_stage_duration_seconds_count", stage="prepare") == 1, "one prepared job (the mesh)")
print("uploads: %d jobs printed; metrics: %d prints, %.2f g" % (len(jobs), done, grams))
PY
stop_sims
check_farm_logs mk3 ender || fail "executed logs differ from the uploaded G-code"

# A stop while an upload is being checked (or stored, or answered: whichever
# the signal meets) ends cleanly: no crash, no leak (the sanitizers' exit
# code), the upload dropped or queued, never half-stored.
$PY -c "
import sys
sys.stdout.write(';FLAVOR:Marlin\n' + 'G1 X10.000 Y10.000 E0.01234\n' * 400000)" > "$tmp/stop.gcode"
sed -i 's/^upload_max_mb: 1$/upload_max_mb: 64/' "$tmp/farm.ini"
kill -HUP "$pid"
wait_for 30 grep -q "upload_max 1048576 -> 67108864" "$tmp/log" || fail "reload of upload_max_mb"
curl -s -o /dev/null -w '%{http_code}' -H "X-Api-Key: $RW" -F "file=@$tmp/stop.gcode" \
  "$SLIMFARM_URL/api/files/local" > "$tmp/stop.code" &
up=$!
for _ in $(seq 100); do grep -q "stop.gcode\|POST" "$tmp/log" 2>/dev/null && break; sleep 0.02; done
sleep 0.2
kill -TERM "$pid"
wait "$pid"; rc=$?
pid=
wait "$up"
[ "$rc" -eq 0 ] || fail "daemon stopped mid-upload with rc $rc"
grep -q "Sanitizer" "$tmp/log" && fail "sanitizer report on a stop mid-upload"
echo "stop mid-upload: the upload was answered '$(cat "$tmp/stop.code")', the daemon exited 0"
echo "farmd_upload: ok"
