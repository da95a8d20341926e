#!/usr/bin/env bash
# tests/integ/farmd_bambu.sh - the mixed farm, every kind of printer in
# one run: slimfarmd with two simulated Marlin printers, an OctoPrint, a
# Klipper behind Moonraker, a Prusa behind PrusaLink, and two simulated
# Bambu printers (an X1 sending full reports, a P1 sending deltas), each
# Bambu behind its own real mosquitto broker with TLS (certificates from
# openssl, CN = serial), reached through the printer's own MQTT port, with
# uploads over the simulators' implicit FTPS.  15 jobs done (14 without an
# OctoPrint simulator in this build), one pinned to each network printer;
# on the way, through the REST API, the X1 is paused and resumed mid-print
# and one more job, on the P1, is stopped.  At the end every job but the
# stopped one is done, the Marlin logs equal their prints' G-code
# (check_farm_logs), the HTTP printers' logs theirs (check_net_logs), and
# each Bambu log is its done prints' G-code in order, the stopped print a
# prefix of its own.  Simulated machines run at --speed 40 to 3000: the
# run takes a few minutes on a loaded machine.
# Skips (exit 0 with a note) when mosquitto or openssl is missing.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
CODE=27182818
. "$(dirname "$0")/lib/bambu.sh"
t0=$(date +%s)

bambu_printer x1 01S00X1000000001 x1 80
bambu_printer p1 01P00P1000000002 p1 200
start_sim mk3 --speed 3000
start_sim mini --speed 3000 --tcp 0
octo=
"$S" octoprint --help > /dev/null 2>&1 && octo=octo
[ -n "$octo" ] && start_net octo octoprint --speed 3000 --api-key octo-key
start_net voron moonraker --speed 3000 --api-key voron-key
start_net mk4 prusalink --speed 3000 --api-key mk4-key
nets="voron mk4 $octo"
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  for m in mk3 mini; do
    printf '[printer %s]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\nauto_eject: true\n' \
      "$m" "$(cat "$tmp/$m.addr")"
  done
  printf '[printer x1]\ndriver: bambu\nhost: 127.0.0.1\nurl: mqtts://127.0.0.1:%s\n' "$mqtt_x1"
  printf 'serial: 01S00X1000000001\naccess_code: %s\nca_file: %s/x1-certs/ca.pem\n' "$CODE" "$tmp"
  printf 'ftps_port: %s\nmaterial: PLA\nauto_eject: true\nbed_size: 256, 256, 256\n' "$ftps_x1"
  printf '[printer p1]\ndriver: bambu\nurl: mqtts://127.0.0.1:%s\n' "$mqtt_p1"
  printf 'serial: 01P00P1000000002\naccess_code: %s\nca_file: %s/p1-certs/ca.pem\n' "$CODE" "$tmp"
  printf 'ftps_port: %s\nmaterial: PLA\nauto_eject: true\nbed_size: 256, 256, 256\n' "$ftps_p1"
  for n in $nets; do
    case $n in octo) d=octoprint ;; voron) d=moonraker ;; mk4) d=prusalink ;; esac
    printf '[printer %s]\ndriver: %s\nurl: %s\napi_key: %s-key\nmaterial: PLA\nauto_eject: true\n' \
      "$n" "$d" "$(cat "$tmp/$n.addr")" "$n"
  done
} > "$tmp/farm.ini"
sed -i '/^host: /d' "$tmp/farm.ini"   # url given: host is its alias, once is enough
"$D" --check -c "$tmp/farm.ini" >/dev/null 2>&1 || fail "--check: $("$D" --check -c "$tmp/farm.ini" 2>&1)"
start_daemon
n_printers=$((4 + $(echo $nets | wc -w)))
wait_for 60 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq $n_printers ]" || fail "printers: $("$C" printers)"

for s in 8 10 12 14 16 18; do tetra "$tmp/t$s.stl" "$s"; done
"$C" shapes "$tmp" > /dev/null || fail "shapes"
j_x1=$(submit "$tmp/frame.stl" --material PLA --printer x1 --method none)
j_p1stop=$(submit "$tmp/lbracket.stl" --material PLA --printer p1 --method none)
done_jobs="$j_x1"
for s in 8 10 12 14 16 18; do done_jobs="$done_jobs $(submit "$tmp/t$s.stl" --material PLA --method none)"; done
for s in 10 14; do done_jobs="$done_jobs $(submit "$tmp/t$s.stl" --material PLA --printer x1 --method none)"; done
for s in 12 16 18; do done_jobs="$done_jobs $(submit "$tmp/t$s.stl" --material PLA --printer p1 --method none)"; done
for n in $nets; do done_jobs="$done_jobs $(submit "$tmp/t12.stl" --material PLA --printer $n --method none)"; done
n_done=$(echo $done_jobs | wc -w)
[ "$n_done" -ge 14 ] || fail "14 jobs or more wanted: $done_jobs"

post() { curl -sf -X POST -H "X-Api-Key: $RW" "$SLIMFARM_URL$1" >/dev/null; }
printer_field() { api "/api/printers/$1" | json "d['printer']['$2']"; }

# pause the X1 mid-print through the REST API; nothing moves while paused; resume
wait_for 240 sh -c "'$C' printers | grep -qE '^x1 +printing .* [1-9][0-9]?%'" || fail "x1 never printed: $("$C" printers)"
post /api/printers/x1/pause || fail "pause x1"
wait_for 60 sh -c "'$C' printers | grep -qE '^x1 +paused'" || fail "x1 not paused: $("$C" printers)"
n1=$(api /api/printers/x1 | json 'd["printer"]["progress"]'); sleep 1; n2=$(api /api/printers/x1 | json 'd["printer"]["progress"]')
[ "$n1" = "$n2" ] || fail "x1 progress moved while paused: $n1 -> $n2"
post /api/printers/x1/resume || fail "resume x1"
wait_for 60 sh -c "'$C' printers | grep -qE '^x1 +printing'" || fail "x1 not printing after resume: $("$C" printers)"

# stop the P1's long job once it prints
wait_for 240 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j_p1stop | /usr/bin/python3 -c 'import json,sys; j=json.load(sys.stdin)[\"job\"]; print(j[\"state\"], j[\"lines_acked\"] > 0)')\" = 'printing True' ]" ||
  fail "job $j_p1stop never printed: $("$C" jobs)"
post "/api/jobs/$j_p1stop/cancel" || post /api/printers/p1/cancel || fail "cancel $j_p1stop"

all_done() { for j in $done_jobs; do [ "$(job_state "$j")" = done ] || return 1; done; }
wait_for 400 all_done || fail "not all done: $("$C" jobs) $("$C" printers)"
[ "$(job_state "$j_p1stop")" = cancelled ] || fail "stopped job: $(job_state "$j_p1stop")"
api "/api/jobs/$j_x1" | json 'd["prints"][0]["printer"]' | grep -qx x1 || fail "x1 job printed elsewhere"

sleep 0.5
stop_sims
check_farm_logs mk3 mini || fail "Marlin logs differ from the jobs' G-code"
check_net_logs $nets || fail "HTTP printers' logs differ from the jobs' G-code"
# Bambu logs: done prints whole, in order; the stopped one a prefix.
/usr/bin/python3 - "$tmp" x1 p1 <<'PY' || fail "Bambu logs differ from the jobs' G-code"
import glob, json, os, re, sys
tmp, printers = sys.argv[1], sys.argv[2:]
host = re.compile(r"^(M105|M110( N-?\d+)?|M400)$")  # the machine's host queries (sim_netprinter.h)
def commands(path):
    return [c for c in (re.sub(r"\s+", " ", re.sub(r";.*", "", l)).strip() for l in open(path))
            if c and not host.match(c)]
cancel_script = ["M104 S0", "M140 S0", "M107", "M84"]  # sim_netprinter.c's
prints = []
for f in glob.glob(os.path.join(tmp, "job-*.json")):
    d = json.load(open(f))
    for p in d["prints"]:
        prints.append((p["started_ms"], p["printer"], p["outcome"], d["job"]["gcode_sha"], d["job"]["id"],
                       p["lines_acked"]))
prints.sort()
bad = 0
for name in printers:
    got = commands(os.path.join(tmp, name + ".log"))
    i = 0
    mine = [p for p in prints if p[1] == name]
    for _, _, outcome, sha, job, acked in mine:
        if outcome not in ("done", "", "cancelled") and acked == 0:
            continue  # failed before it ran (an upload that failed; the job was retried)
        want = commands(glob.glob(os.path.join(tmp, "data", "**", sha + "*"), recursive=True)[0])
        if outcome in ("done", ""):
            if got[i:i + len(want)] != want:
                print("%s: job %d: log differs from its G-code at log line %d" % (name, job, i + 1)); bad += 1; break
            i += len(want)
        else:
            k = 0
            while i < len(got) and k < len(want) and got[i] == want[k]:
                i += 1; k += 1
            if k == 0 or k == len(want) or got[i:i + 4] != cancel_script:
                print("%s: %s job %d ran %d of %d lines, then %r" % (name, outcome, job, k, len(want), got[i:i + 4])); bad += 1; break
            i += 4
    if not bad and i != len(got):
        print("%s: %d log lines after the last print" % (name, len(got) - i)); bad += 1
    print("  %s: %d prints, %d log lines" % (name, len(mine), len(got)))
sys.exit(1 if bad else 0)
PY
done_on() { /usr/bin/python3 -c "
import glob, json
print(sum(1 for f in glob.glob('$tmp/job-*.json') for p in json.load(open(f))['prints']
          if p['printer'] == '$1' and p['outcome'] == 'done'))"; }
n_x1=$(done_on x1); n_p1=$(done_on p1)
[ "$n_x1" -ge 3 ] && [ "$n_p1" -ge 3 ] || fail "Bambu printers did too little: x1 $n_x1, p1 $n_p1 done"
for n in $nets; do [ "$(done_on $n)" -ge 1 ] || fail "$n finished no print"; done
kill -TERM $pid; wait $pid; pid=
echo "farmd_bambu: ok ($n_done jobs done, 1 stopped, on 2 Marlin + $(echo $nets | wc -w) HTTP + 2 Bambu printers in $(( $(date +%s) - t0 )) s)"
