#!/usr/bin/env bash
# tests/check-layers.sh - enforce the dependency rule of the code map:
# a folder may include headers only from folders before it in
#   src/base src/mesh src/geom slicer drivers src/farm src/api src/cmd
# and sim/ may include only src/base.  drivers/ and sim/ hold family folders
# (drivers/marlin, sim/net, ...): a family folder ranks as its top folder, so
# families may include each other and their top folder's headers.
set -u
order=(src/base src/mesh src/geom slicer drivers src/farm src/api src/cmd)
# drivers/net -> drivers, sim/bambu -> sim; other folders are their own layer.
layer() { case "$1" in drivers/*) echo drivers ;; sim/*) echo sim ;; *) echo "$1" ;; esac; }
rank() { local i; for i in "${!order[@]}"; do [ "${order[$i]}" = "$1" ] && { echo "$i"; return; }; done; echo -1; }
bad=0
while IFS= read -r f; do
  dir=$(dirname "$f")
  lay=$(layer "$dir")
  while IFS= read -r inc; do
    # resolve the include relative to the including file
    target=$(realpath -m --relative-to=. "$dir/$inc")
    tdir=$(layer "$(dirname "$target")")
    [ "$tdir" = "$lay" ] && continue
    case "$tdir" in tests*|src/base) [ "$tdir" = src/base ] && continue ;; esac
    if [ "$lay" = sim ]; then
      echo "$f: sim/ may include only src/base, not $target"; bad=1; continue
    fi
    fr=$(rank "$lay"); tr=$(rank "$tdir")
    if [ "$fr" -ge 0 ] && [ "$tr" -ge 0 ] && [ "$tr" -gt "$fr" ]; then
      echo "$f: includes $target, but $tdir comes after $lay in the layer order"; bad=1
    fi
  done < <(grep -oE '^#include "[^"]+"' "$f" | sed -E 's/#include "(.*)"/\1/')
done < <(git ls-files 'src/*' 'slicer/*' 'drivers/*' 'sim/*' | grep -E '\.(c|h|cpp)$')
[ $bad -eq 0 ] && echo "layers: ok"
exit $bad
