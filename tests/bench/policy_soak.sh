#!/usr/bin/env bash
# tests/bench/policy_soak.sh - the G-code policy's soak (issue 29): N (200)
# G-code files, each a short real print (heat, G28, a few hundred extruding
# G1 moves, end) carrying 0-3 lines drawn at random from the policy's rows
# (README "The G-code policy": M110, M111, M117/M118 host replies, EEPROM
# and firmware commands, waits for a person, M112/M108/M410, NUL, control
# and non-ASCII bytes, SAVE_CONFIG, FIRMWARE_RESTART) and from lines that
# pass (M117 Layer 3, M118 E1 hello, non-ASCII inside a comment), at random
# places, uploaded to POST /api/files/local of a slimfarmd with 4 simulated
# unattended Marlin printers.  The expectation is computed here from the
# rows injected, not by asking the policy.  Checks: each file the policy
# must refuse got a 400 naming exactly its offending lines (and no job);
# each other file became one job printed exactly once, done; each
# printer's executed log holds every print's command lines once, in order
# (lib/farm.sh check_farm_logs); at the end every printer is idle.  Waits
# are bounded.  SEED=S replays a run (the seed is printed), N=20 is a quick
# run, SPEED (5000) sets the simulators' speed.  `make soak` runs it
# (tests/bench/soak.sh).  Exit 1 on a failure.
set -u
BUILD=${BUILD:-${1:-build/rel}}
N=${N:-200}
SEED=${SEED:-$(od -An -N4 -tu4 /dev/urandom | tr -d ' ')}
names="p1 p2 p3 p4"
. "$(dirname "$0")/../integ/lib/farm.sh"
t0=$(date +%s)
echo "policy_soak: SEED=$SEED N=$N"

for p in $names; do start_sim "$p" --speed "${SPEED:-5000}"; done
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  for p in $names; do
    printf '[printer %s]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' "$p" "$(cat "$tmp/$p.addr")"
    printf 'auto_eject: true\ngcode_models: *\n'
  done
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 4 ]" || fail "printers: $("$C" printers)"

PORT=$http_port RW=$RW TMP=$tmp N=$N SEED=$SEED /usr/bin/python3 - "$(dirname "$0")/../integ/lib" <<'PY' || fail "policy soak"
import json, os, random, re, sys, time
from concurrent.futures import ThreadPoolExecutor
sys.path.insert(0, sys.argv[1])
from slicers import curl_get, prusaslicer
port, rw, tmp = int(os.environ["PORT"]), os.environ["RW"], os.environ["TMP"]
n_files, seed = int(os.environ["N"]), int(os.environ["SEED"])
rng = random.Random(seed)
bad = []

# (line, what the 400 names after "line N: ", or None when the policy passes it)
ROWS = [(b"M110 N5", "M110"), (b"M111 S7", "M111"), (b"M118 Resend: 1", "M118"),
        (b"M118 ok", "M118"), (b"M117 ok", "M117"), (b"M500", "M500"), (b"M502", "M502"),
        (b"M997", "M997"), (b"M999", "M999"), (b"M0", "M0"), (b"M1", "M1"), (b"M600", "M600"),
        (b"M25", "M25"), (b"M226", "M226"), (b"M112", "M112"), (b"M108", "M108"),
        (b"M410", "M410"), (b"SAVE_CONFIG", "SAVE_CONFIG"),
        (b"FIRMWARE_RESTART", "FIRMWARE_RESTART"), (b"M117 Layer 3", None),
        (b"M118 E1 hello", None), (b"G1 X12 Y12 ; 200 \xc2\xb0C", None),
        ("nul",), ("control",), ("nonascii",)]

def draw():
    r = rng.choice(ROWS)
    if r[0] == "nul":
        return rng.choice([b"G1 X10\x00 Y10", b"\x00G1 X10", b"G1 X10 ; \x00"]), "byte 0x00"
    if r[0] == "control":  # not TAB or LF; a CR only inside a line (it may end one)
        c = bytes([rng.choice([c for c in range(1, 32) if c not in (9, 10)] + [0x7f])])
        line = b"G1 X10 Y10" + c + b" F3000"
        if c != b"\r" and rng.random() < 0.5:
            line = b"G1 X10 Y10 ; in a comment " + c
        return line, "byte 0x%02x" % c[0]
    if r[0] == "nonascii":
        c = rng.randrange(0x80, 0x100)
        return b"M117 T=200" + bytes([c]), "byte 0x%02x" % c
    return r

def make(i):
    lines = [b"; policy soak file %d, seed %d" % (i, seed), b"G90", b"M83", b"M140 S60",
             b"M104 S200", b"G28", b"M190 S60", b"M109 S200", b"G92 E0"]
    x, y = 100.0, 100.0
    for k in range(rng.randrange(150, 300)):
        x = min(190, max(10, x + rng.uniform(-5, 5)))
        y = min(190, max(10, y + rng.uniform(-5, 5)))
        lines.append(b"G1 X%.2f Y%.2f E%.4f F%d" % (x, y, rng.uniform(0.01, 0.2), 1200 + 300 * (k % 4)))
    lines += [b"M104 S0", b"M140 S0", b"G1 X10 Y190 F6000", b"M84"]
    want = []  # (line number, name) of each line the policy must refuse
    for _ in range(rng.choice([0, 0, 1, 1, 2, 3])):
        text, name = draw()
        pos = rng.randrange(0, len(lines) + 1)
        lines.insert(pos, text)
        want = [(n + 1 if n > pos else n, w) for n, w in want]
        if name:
            want.append((pos + 1, name))
    return b"\n".join(lines) + b"\n", sorted(want)

files = [make(i) for i in range(n_files)]

def upload(i):
    data, want = files[i]
    name = "soak-%03d.gcode" % i
    st, h, b = prusaslicer(port, rw, name, data)
    if want:
        err = json.loads(b).get("error", "") if st == 400 else ""
        named = sorted(set(int(m) for m in re.findall(r"line (\d+):", err)))
        if st != 400 or not err.startswith("G-code '%s': line " % name):
            return "%s: want a 400 for %r, got %d %s" % (name, want, st, b[:200])
        for n, w in want:
            if " line %d: %s: " % (n, w) not in err:
                return "%s: %r not named in %r" % (name, "line %d: %s" % (n, w), err[:400])
        if named != sorted(set(n for n, _ in want)):
            return "%s: named lines %r, want %r: %r" % (name, named, want, err[:400])
        return None
    if st != 201:
        return "%s: want 201, got %d %s" % (name, st, b[:300])
    return ("job", json.loads(b)["slimfarm"]["job_id"], i)

with ThreadPoolExecutor(4) as ex:
    results = list(ex.map(upload, range(n_files)))
jobs = {}
for r in results:
    if isinstance(r, tuple):
        jobs[r[1]] = r[2]
    elif r:
        bad.append(r)
refused = sum(1 for d, w in files if w)
print("  uploaded %d files: %d refused, %d jobs" % (n_files, refused, len(jobs)))

def get(path):
    st, h, b = curl_get(port, path, "soak", rw)
    if st != 200:
        sys.exit("FAIL: GET %s: %d %s" % (path, st, b[:200]))
    return json.loads(b)

# every job ends (bounded: no job state changes for 120 s, or 2 s a file)
end, last, seen = time.time() + 60 + 2 * n_files, time.time(), None
while time.time() < end and time.time() - last < 120:
    states = {j["id"]: j["state"] for j in get("/api/jobs")["jobs"]}
    if states != seen:
        seen, last = states, time.time()
    if all(s in ("done", "failed", "cancelled", "interrupted") for s in states.values()):
        break
    time.sleep(1)
if set(seen) != set(jobs):
    bad.append("jobs %r, uploads accepted %r (a refused upload left a job?)"
               % (sorted(set(seen) - set(jobs)), sorted(set(jobs) - set(seen))))
printed = 0
for jid in sorted(jobs):
    d = get("/api/jobs/%d" % jid)
    outs = [(p["printer"], p["outcome"]) for p in d["prints"]]
    if d["job"]["state"] != "done" or len(outs) != 1 or outs[0][1] != "done":
        bad.append("job %d (soak-%03d.gcode): state %s, prints %r" % (jid, jobs[jid], d["job"]["state"], outs))
    else:
        printed += 1
stored = sum(len(f) for _, _, f in os.walk(os.path.join(tmp, "data", "files")))
if stored != len(jobs):
    bad.append("%d files stored for %d jobs" % (stored, len(jobs)))
for p in get("/api/printers")["printers"]:
    if p["state"] != "idle" or p.get("job_id"):
        bad.append("printer %s ends %s: %r" % (p["name"], p["state"], p))
open(os.path.join(tmp, "counts"), "w").write("%d %d\n" % (refused, printed))
for b in bad[:20]:
    print("FAIL:", b)
sys.exit(1 if bad else 0)
PY
stop_sims
check_farm_logs $names || fail "executed logs differ from the printed jobs (SEED=$SEED)"
read -r refused printed < "$tmp/counts"
secs=$(($(date +%s) - t0))
echo "policy_soak: ok: SEED=$SEED files $N, refused $refused, printed $printed, $((secs / 60)).$((secs % 60 * 10 / 60)) minutes"
