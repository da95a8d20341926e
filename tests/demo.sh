#!/usr/bin/env bash
# tests/demo.sh [--once] - the main job on embedded defaults.
# Today: generate the demo parts, orient each for the least support, and
# show support before and after (ray-cast volume on a 1 mm grid, 45 deg).
# The farm daemon, simulated printers and the print summary join as they
# land (issue 7).
set -euo pipefail
cd "$(dirname "$0")/.."
data=${SLIMFARM_DEMO_DIR:-demo-data}
rm -rf "$data"; mkdir -p "$data/parts" "$data/oriented"
bin/slimfarm shapes "$data/parts" >/dev/null
printf '%-14s %9s %14s %14s %9s %s\n' part triangles "support mm3" "oriented mm3" seconds up
for part in "$data"/parts/*.stl; do
  name=$(basename "$part")
  bin/slimfarm orient "$part" -o "$data/oriented/$name" --json | /usr/bin/python3 -c '
import json, sys
r = json.load(sys.stdin); b, i = r["best"], r["input"]
print("%-14s %9s %14.0f %14.0f %9.2f (%.2f, %.2f, %.2f) %s" % (sys.argv[1], sys.argv[2],
      i["support_volume_mm3"], b["support_volume_mm3"], r["seconds"], *b["up"], b["source"]))' \
    "$name" "$(bin/slimfarm inspect --json "$part" | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)["mesh"]["triangles"])')"
done
echo "oriented parts are in $data/oriented/"
