#!/usr/bin/env bash
# tests/browser/dashboard.sh - the dashboard in a real browser: slimfarmd
# with two simulated Marlin printers (mk3 waits for its bed to be cleared,
# mini clears its own), Debian's chromium driven headless by playwright-core
# (tests/browser/dashboard.mjs does the clicking; this script starts the
# farm and hands it what it needs in the environment): log in, submit parts
# through the form (file input and drag and drop), watch them print without
# a reload, Bed cleared, reorder and cancel queued jobs, pause and resume a
# print, accessible names, a read-only key without buttons, and the daemon
# killed mid-print under the open page (banner, recovery, then resuming the
# interrupted job from its line).  Screenshots land in build/browser/.
# Skips (passes, saying so) when chromium or node is absent: `make check`
# installs both.
set -u
umask 077 # slimfarmd refuses a config holding keys that others can read
BUILD=${BUILD:-build/san}
here=$(cd "$(dirname "$0")" && pwd)
if [ ! -x /usr/bin/chromium ] || ! command -v node > /dev/null ||
  [ ! -f "$here/node_modules/playwright-core/package.json" ]; then
  echo "dashboard: skipped (chromium, node or playwright-core missing: make browser-deps)"
  exit 0
fi
. "$here/../integ/lib/farm.sh"
RO=ro-key-0123456789abcdef

start_sim mk3 --speed 3000
start_sim mini --speed 100
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\napi_keys_readonly: %s\n' \
    "$port" "$tmp" "$RW" "$RO"
  printf '[printer mk3]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 210\nauto_eject: false\n' \
    "$(cat "$tmp/mk3.addr")"
  printf '[printer mini]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 180, 180, 180\nauto_eject: true\n' \
    "$(cat "$tmp/mini.addr")"
} > "$tmp/farm.ini"
start_daemon
pin_port # the script restarts the daemon under the open page: same URL
wait_for 60 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 2 ]" || fail "printers: $("$C" printers)"
"$C" shapes "$tmp/parts" > /dev/null || fail "shapes"

shots=$(pwd)/build/browser
mkdir -p "$shots"
rm -f "$shots"/*.png
# the script kills the daemon once and starts it again; it writes the new
# pid to $tmp/daemon.pid so cleanup can stop it
SF_URL=$SLIMFARM_URL SF_RW=$RW SF_RO=$RO SF_PARTS=$tmp/parts SF_SHOTS=$shots \
  SF_DAEMON="$D" SF_CONFIG="$tmp/farm.ini" SF_LOG="$tmp/log" SF_PID=$pid SF_PIDFILE=$tmp/daemon.pid \
  timeout 540 node "$here/dashboard.mjs" || {
  [ -s "$tmp/daemon.pid" ] && pid=$(cat "$tmp/daemon.pid")
  fail "the browser test failed"
}
[ -s "$tmp/daemon.pid" ] && pid=$(cat "$tmp/daemon.pid")
kill -TERM "$pid"; wait "$pid" 2>/dev/null; pid=
echo "dashboard: ok (screenshots in $shots)"
