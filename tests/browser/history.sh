#!/usr/bin/env bash
# tests/browser/history.sh - the history page (src/api/web/history.*) in a
# real browser: slimfarmd with one simulated Marlin printer that clears its
# own bed; tests/browser/history.mjs prints a job to the end, cancels
# another, then filters the page by outcome and name, follows its CSV
# link, prints a job again from it, and checks accessibility.  Skips
# (passes, saying so) when chromium, node or the npm packages are absent:
# `make check` installs them.
set -u
umask 077
BUILD=${BUILD:-build/san}
here=$(cd "$(dirname "$0")" && pwd)
if [ ! -x /usr/bin/chromium ] || ! command -v node > /dev/null ||
  [ ! -f "$here/node_modules/playwright-core/package.json" ] ||
  [ ! -f "$here/node_modules/axe-core/axe.min.js" ]; then
  echo "history: skipped (chromium, node, playwright-core or axe-core missing: make browser-deps)"
  exit 0
fi
. "$here/../integ/lib/farm.sh"

start_sim mk3 --speed 3000
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf '[printer mk3]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 210\nauto_eject: true\n' \
    "$(cat "$tmp/mk3.addr")"
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 1 ]" || fail "printers: $("$C" printers)"
"$C" shapes "$tmp/parts" > /dev/null || fail "shapes"

shots=$(pwd)/build/browser/history # dashboard.sh empties build/browser
mkdir -p "$shots"
rm -f "$shots"/*.png
SF_URL=$SLIMFARM_URL SF_RW=$RW SF_PARTS=$tmp/parts SF_SHOTS=$shots \
  timeout 540 node "$here/history.mjs" || fail "the browser test failed"
kill -TERM "$pid"; wait "$pid" 2>/dev/null; pid=
echo "history: ok (screenshot in $shots)"
