#!/usr/bin/env bash
# tests/browser/printers.sh - printers managed at run time from the
# dashboard, in a real browser (tests/browser/printers.mjs does the
# clicking): a farm.ini with one printer ("seed", a simulated Marlin) and a
# second simulated Marlin the page adds as "mk" through its Add printer
# form, then disables with a reason, enables and removes.  Screenshots land
# in build/browser/printers/.  Skips (passes, saying so) when chromium,
# node or the npm packages are absent: `make check` installs them.
name=printers
. "$(dirname "$0")/lib/browser.sh"

start_sim seed --speed 100
start_sim mk --speed 100
one_printer_ini seed true
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^seed +idle'" || fail "printers: $("$C" printers)"

shots=$(pwd)/build/browser/printers
mkdir -p "$shots"
rm -f "$shots"/*.png
SF_URL=$SLIMFARM_URL SF_RW=$RW SF_SHOTS=$shots SF_MK_PORT=$(cat "$tmp/mk.addr") \
  timeout 600 node "$here/printers.mjs" || fail "the browser test failed"
kill -TERM "$pid"; wait "$pid" 2>/dev/null; pid=
echo "printers: ok (screenshots in $shots)"
