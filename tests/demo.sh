#!/usr/bin/env bash
# tests/demo.sh [--once] - the main job on embedded defaults.
# Today: generate the demo parts and inspect each (mesh report and support
# metrics as printed and ray-cast).  The farm daemon, simulated printers and
# the print summary join as they land (issue 7).
set -euo pipefail
cd "$(dirname "$0")/.."
data=${SLIMFARM_DEMO_DIR:-demo-data}
rm -rf "$data"; mkdir -p "$data/parts"
bin/slimfarm shapes "$data/parts" >/dev/null
printf '%-14s %9s %8s %12s %14s %8s\n' part triangles closed "risky mm2" "support mm3" anchors
for part in "$data"/parts/*.stl; do
  bin/slimfarm inspect --json "$part" | /usr/bin/python3 -c '
import json, os, sys
r = json.load(sys.stdin); s = r["support"]
print("%-14s %9d %8s %12.0f %14.0f %8d" % (os.path.basename(r["file"]), r["mesh"]["triangles"],
      "yes" if r["closed"] else "no", s["risky_area_mm2"], s["support_volume_mm3"], s["anchors"]))'
done
