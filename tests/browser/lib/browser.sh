# tests/browser/lib/browser.sh - what the browser tests' scripts share (sourced with
# $name set): skip, passing and saying so, when chromium, node or the npm
# packages are absent (`make check` installs them); then the farm helpers
# (tests/integ/lib/farm.sh).
set -u
umask 077 # slimfarmd refuses a config holding keys that others can read
BUILD=${BUILD:-build/san}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [ ! -x /usr/bin/chromium ] || ! command -v node > /dev/null ||
  [ ! -f "$here/node_modules/playwright-core/package.json" ] ||
  [ ! -f "$here/node_modules/axe-core/axe.min.js" ]; then
  echo "$name: skipped (chromium, node, playwright-core or axe-core missing: make browser-deps)"
  exit 0
fi
. "$here/../integ/lib/farm.sh"

# browser_run IDLE SCRIPT [VAR=VALUE...]: start slimfarmd on $tmp/farm.ini,
# wait for IDLE idle printers, make the parts, run tests/browser/SCRIPT with
# the farm (and the VARs) in its environment, screenshots going to
# build/browser/$name, then stop the daemon.
browser_run() {
  local idle=$1 script=$2
  shift 2
  start_daemon
  wait_for 120 sh -c "[ \$('$C' printers | grep -c ' idle ') -ge $idle ]" || fail "printers: $("$C" printers)"
  "$C" shapes "$tmp/parts" > /dev/null || fail "shapes"
  shots=$(pwd)/build/browser/$name # dashboard.sh empties build/browser
  mkdir -p "$shots"
  rm -f "$shots"/*.png
  env SF_URL="$SLIMFARM_URL" SF_RW="$RW" SF_PARTS="$tmp/parts" SF_SHOTS="$shots" "$@" \
    timeout 600 node "$here/$script" || fail "the browser test failed"
  kill -TERM "$pid"
  wait "$pid" 2> /dev/null
  pid=
}
