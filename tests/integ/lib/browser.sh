# tests/integ/lib/browser.sh NAME - the start of a browser test
# (tests/browser/NAME.sh): strict mode, private files (slimfarmd refuses a
# farm.ini holding keys that others can read), the build to test; then,
# when chromium, node, playwright-core or axe-core is missing, say NAME is
# skipped and exit 0 (a skip passes; `make check` installs them), else
# source lib/farm.sh.  Sourced, not run.
set -u
umask 077
BUILD=${BUILD:-build/san}
browser_mods=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../browser" && pwd)/node_modules
if [ ! -x /usr/bin/chromium ] || ! command -v node > /dev/null ||
  [ ! -f "$browser_mods/playwright-core/package.json" ] ||
  [ ! -f "$browser_mods/axe-core/axe.min.js" ]; then
  echo "$1: skipped (chromium, node, playwright-core or axe-core missing: make browser-deps)"
  exit 0
fi
. "$(dirname "${BASH_SOURCE[0]}")/farm.sh"
