#!/usr/bin/env bash
# tests/browser/history.sh - the history page (src/api/web/history.*) in a
# real browser: slimfarmd with one simulated Marlin printer that clears its
# own bed; tests/browser/history.mjs prints a job to the end, cancels
# another, then filters the page by outcome and name, follows its CSV
# link, prints a job again from it, and checks accessibility.  Skips
# (passes, saying so) when chromium, node or the npm packages are absent:
# `make check` installs them.
name=history
. "$(dirname "$0")/lib/browser.sh"

start_sim mk3 --speed 3000
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf '[printer mk3]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 210\nauto_eject: true\n' \
    "$(cat "$tmp/mk3.addr")"
} > "$tmp/farm.ini"
browser_run 1 history.mjs
echo "history: ok (screenshot in build/browser/history)"
