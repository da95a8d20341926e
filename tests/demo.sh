#!/usr/bin/env bash
# tests/demo.sh [--once] - the main job on embedded defaults: a farm of three
# simulated Marlin printers (two on ptys, one behind a TCP serial bridge),
# slimfarmd on a fresh SQLite data dir, and the generated demo parts queued
# on it.  Each part is oriented (the mushroom is also slimmed, the torus
# reshaped by the surface method), sliced for
# its printer, and printed at simulation speed; the run ends with a summary
# table.  With --once it exits there; otherwise the farm keeps running
# (http://127.0.0.1:$PORT, key below) until Ctrl-C.
#
# The API key is made fresh each run (24 random bytes, printed below), never
# a fixed one a neighbour could read here; the config holding it and the
# data dir are the user's alone (umask 077).  --key prints a fresh key the
# way a run makes it, and exits (tests/integ/demo_key.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
umask 077
demo_key() { head -c 24 /dev/urandom | base64 | tr '+/' '-_'; }
[ "${1:-}" = --key ] && { demo_key; exit 0; }
once=0; [ "${1:-}" = --once ] && once=1
data=${SLIMFARM_DEMO_DIR:-demo-data}
port=${SLIMFARM_DEMO_PORT:-7420}
key=$(demo_key)
rm -rf "$data"; mkdir -p "$data/parts" "$data/sim"
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; }
trap cleanup EXIT INT TERM

bin/slimfarm shapes "$data/parts" > /dev/null
# simulated printers: fast (speed x500), 1 Mbaud, one on TCP like a ser2net bridge
start_sim() { # NAME ARGS...: started here, not in a subshell, so cleanup can stop it
  local name=$1; shift
  bin/slimfarm-sim marlin --baud 1000000 --speed 500 --advanced-ok "$@" \
    > "$data/sim/$name.out" 2> "$data/sim/$name.err" &
  pids+=($!)
}
addr() { # NAME: the simulator's pty path or tcp:// address (its first line)
  for _ in $(seq 100); do [ -s "$data/sim/$1.out" ] && break; sleep 0.05; done
  head -n 1 "$data/sim/$1.out"
}
start_sim mk3
start_sim ender
start_sim voron --tcp 0
mk3=$(addr mk3)
ender=$(addr ender)
voron=$(addr voron)
case "$mk3" in /dev/*) mk3="pty:$mk3" ;; esac
case "$ender" in /dev/*) ender="pty:$ender" ;; esac
cp -r config/printers config/materials "$data/"
cat > "$data/farm.ini" <<INI
[farm]
listen: 127.0.0.1:$port
data_dir: $data/db
api_keys: $key
[printer mk3]
driver: marlin
port: $mk3
baud: 1000000
profile: prusa-mk3s
material: PLA
bed_size: 250, 210, 210
auto_eject: true
[printer ender]
driver: marlin
port: $ender
baud: 1000000
material: PLA
bed_size: 220, 220, 250
auto_eject: true
[printer voron]
driver: marlin
port: $voron
material: PLA
bed_size: 300, 300, 300
auto_eject: true
INI
bin/slimfarmd -c "$data/farm.ini" > "$data/slimfarmd.log" 2>&1 &
pids+=($!)
export SLIMFARM_URL=http://127.0.0.1:$port SLIMFARM_API_KEY=$key
for _ in $(seq 100); do bin/slimfarm printers > /dev/null 2>&1 && break; sleep 0.1; done
echo "slimfarmd on $SLIMFARM_URL (open it in a browser for the dashboard; API key $key); printers: mk3 ($mk3), ender ($ender), voron ($voron)"
for part in tee arch lbracket frame; do
  bin/slimfarm submit "$data/parts/$part.stl" --material PLA > /dev/null
done
bin/slimfarm submit "$data/parts/torus.stl" --material PLA --method surface --deviation 3 > /dev/null
bin/slimfarm submit "$data/parts/mushroom.stl" --material PLA --method slim --deviation 3 > /dev/null

# wait for every job to end, showing the farm as it goes
api() { curl -sf -H "X-Api-Key: $key" "$SLIMFARM_URL$1"; }
last=
for _ in $(seq 900); do
  states=$(api /api/jobs | /usr/bin/python3 -c 'import json,sys; print(" ".join(j["state"] for j in json.load(sys.stdin)["jobs"]))')
  if [ -t 2 ]; then printf '\r%s' "jobs: $states   " >&2
  elif [ "$states" != "$last" ]; then echo "jobs: $states" >&2; fi
  last=$states
  [[ " $states " =~ \ (queued|preparing|ready|printing|paused)\  ]] || break
  sleep 1
done
[ -t 2 ] && echo >&2

# summary: support grams as uploaded (sliced here, same profile) and as printed
printf '%-14s %-8s %-7s %-6s %10s %10s %9s %s\n' part method state printer "sup g in" "sup g out" "print min" "lines"
api /api/jobs | /usr/bin/python3 -c 'import json,sys
for j in json.load(sys.stdin)["jobs"]: print(j["id"], j["name"], j["method"], j["state"], j["gcode_sha"] or "-")' |
while read -r id name method state sha; do
  read -r printer lines < <(api "/api/jobs/$id" | /usr/bin/python3 -c 'import json,sys
p = json.load(sys.stdin)["prints"]; print(p[-1]["printer"], p[-1]["lines_acked"]) if p else print("- 0")')
  before=$(bin/slimfarm slice "$data/parts/$name" -o "$data/raw-$name.gcode" 2>/dev/null | true;
           sed -n 's/^; support material used \[g\] = //p' "$data/raw-$name.gcode" 2>/dev/null | head -1)
  gcode=$(find "$data/db" -type f -name "$sha*" 2>/dev/null | head -1)
  after=$(sed -n 's/^; support material used \[g\] = //p' "$gcode" 2>/dev/null | head -1)
  mins=$(sed -n 's/^; estimated printing time \[s\] = //p' "$gcode" 2>/dev/null | head -1)
  printf '%-14s %-8s %-7s %-6s %10s %10s %9s %s\n' "$name" "$method" "$state" "$printer" \
    "${before:--}" "${after:--}" "$( [ -n "$mins" ] && echo $((mins / 60)) || echo -)" "$lines"
done
if [ "$once" = 0 ]; then
  echo "the farm keeps running: slimfarm jobs | printers | watch (SLIMFARM_URL and SLIMFARM_API_KEY as above); Ctrl-C stops"
  wait
fi
