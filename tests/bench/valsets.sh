#!/usr/bin/env bash
# valsets.sh SET... - the meshes of the benchmark sets, one "SET PATH" line
# each (tab-separated), generating them first when they are not cached:
#   shared  ../shared/meshes/*.stl, the tuning set (SLIMFARM_SHARED moves it)
#   mech    mechanical parts from the parametric family tests/bench/valsets/
#           (OpenSCAD templates mech/*.scad, parameters drawn from a fixed
#           seed by gen.py: boxes and lids, an enclosure, plates on
#           standoffs, bosses, brackets, bores and teardrops, bridged slots,
#           a hook, a clip, a shelf, a threaded boss), 16 parts, 20-120 mm
#   scad    OpenSCAD's shipped examples (/usr/share/openscad/examples, Debian
#           package openscad, licence CC0-1.0), the printable solids that need
#           support in some orientation, exported to STL by its CLI
#   all     shared mech scad
# Validation sets (mech, scad) are measured on, never tuned on.  The parts
# are generated into VALSET_DIR (default build/valsets)/SET-KEY, KEY the
# first 8 hex of the md5 of the templates, gen.py, the seed and OpenSCAD's
# version, so a changed template makes a new set; never committed.
# VALSET_SEED (default 14) draws another family; VALSET_PARTS="lid_up hook"
# generates and lists only those parts (into their own folder).  A set that
# cannot be made (openscad missing: make bench installs it) is left out
# with a message on stderr; exit status 3 when any was.
set -u
here=$(cd "$(dirname "$0")" && pwd)
shared=${SLIMFARM_SHARED:-../shared}
root=${VALSET_DIR:-build/valsets}
sets=("$@")
[ ${#sets[@]} = 0 ] && sets=(shared)
[ "${sets[*]}" = all ] && sets=(shared mech scad)
rc=0
for s in "${sets[@]}"; do
  case $s in
    shared)
      if [ -d "$shared/meshes" ]; then
        for f in $(ls -S -r "$shared"/meshes/*.stl); do printf 'shared\t%s\n' "$f"; done
      else
        echo "valsets: $shared/meshes absent, set shared left out" >&2; rc=3
      fi ;;
    mech | scad)
      if ! command -v openscad >/dev/null; then
        echo "valsets: openscad missing (apt-get install openscad; make bench installs it), set $s left out" >&2
        rc=3; continue
      fi
      key=$( { cat "$here"/valsets/gen.py "$here"/valsets/mech/*.scad; echo "${VALSET_SEED:-14}";
               openscad --version 2>&1; } | md5sum | cut -c1-8)
      names=${VALSET_PARTS:-}
      dir="$root/$s-$key${names:+-$(echo "$names" | md5sum | cut -c1-6)}"
      if [ ! -f "$dir/done" ]; then
        rm -rf "$dir.tmp"; mkdir -p "$dir.tmp"
        # shellcheck disable=SC2086
        if ! nice python3 "$here/valsets/gen.py" "$s" "$dir.tmp" $names >&2; then
          echo "valsets: generating $s failed, set left out" >&2; rm -rf "$dir.tmp"; rc=3; continue
        fi
        touch "$dir.tmp/done"; rm -rf "$dir"; mv "$dir.tmp" "$dir"
      fi
      for n in ${names:-$(python3 "$here/valsets/gen.py" list "$s")}; do
        [ -s "$dir/$n.stl" ] && printf '%s\t%s\n' "$s" "$dir/$n.stl"
      done ;;
    *) echo "valsets: unknown set '$s' (shared, mech, scad, all)" >&2; exit 2 ;;
  esac
done
exit $rc
