#!/usr/bin/env bash
# tests/browser/cards.sh - the dashboard's printer cards, guarded actions,
# layer preview and accessibility in a real browser, on a farm of 24
# simulated printers in states an operator meets (tests/browser/cards.mjs
# does the clicking; this script starts the farm):
#   slow  heats and prints at real speed (a 3-copy job whose copy is stopped
#         from the card), keeps its part until the bed is cleared
#   hot   a thermal runaway after 3000 commands (in its first job): error, then Clear error
#   gone  answers, then its simulator is killed: offline
#   off   disabled in farm.ini
#   fast  prints an arc-fitted torus quickly (the layer preview)
#   p0..p18  idle printers (one simulator serves them), for the grid at scale
# Screenshots (1280x800, 1920x1080, 390x844) land in build/browser/cards/.
# Skips (passes, saying so) when chromium, node or the npm packages are
# absent: `make check` installs them.
here=$(cd "$(dirname "$0")" && pwd)
. "$here/../integ/lib/browser.sh" cards

start_sim slow --speed 1
start_sim hot --speed 3000 --fault runaway=3000
start_sim gone --speed 100 --tcp 0 # killed: a TCP port nobody takes again, not a pty path another test may get
start_sim fast --speed 3000
# one simulator process serving the idle printers of the big grid
"$S" marlin --baud 1000000 --advanced-ok --speed 100 --count 19 > "$tmp/many.out" 2> "$tmp/many.err" &
sims+=($!)
lines() { cat "$tmp/many.out" 2> /dev/null | wc -l; }
for _ in $(seq 600); do [ "$(lines)" -ge 19 ] && break; sleep 0.05; done
[ "$(lines)" -ge 19 ] || fail "the 19 idle simulators did not start: $(cat "$tmp/many.err")"

cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  pr() { # NAME PORT EJECT [MORE]
    printf '[printer %s]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 210\nauto_eject: %s\n%b' \
      "$1" "$2" "$3" "${4:-}"
  }
  pr slow "$(cat "$tmp/slow.addr")" false
  pr hot "$(cat "$tmp/hot.addr")" false
  pr gone "$(cat "$tmp/gone.addr")" true
  pr off /dev/null true 'enabled: false\n'
  pr fast "$(cat "$tmp/fast.addr")" true
  i=0
  while read -r a; do
    case "$a" in /dev/*) a="pty:$a" ;; esac
    pr "p$i" "$a" true
    i=$((i + 1))
  done < "$tmp/many.out"
} > "$tmp/farm.ini"
start_daemon
wait_for 120 sh -c "[ \$('$C' printers | grep -c ' idle ') -ge 23 ]" || fail "printers: $("$C" printers)"
"$C" shapes "$tmp/parts" > /dev/null || fail "shapes"

shots=$(pwd)/build/browser/cards # dashboard.sh empties build/browser
mkdir -p "$shots"
rm -f "$shots"/*.png
SF_URL=$SLIMFARM_URL SF_RW=$RW SF_PARTS=$tmp/parts SF_SHOTS=$shots SF_GONE_PID=$sim_gone \
  timeout 600 node "$here/cards.mjs" || fail "the browser test failed"
kill -TERM "$pid"; wait "$pid" 2>/dev/null; pid=
echo "cards: ok (screenshots in $shots)"
