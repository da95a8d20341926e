#!/usr/bin/env bash
# tests/check-layers.sh - enforce the dependency rule of the code map:
# a folder may include headers only from folders before it in
#   src/base src/mesh src/geom slicer drivers src/farm src/api src/cmd
# and sim/ may include only src/base (plus drivers' pure linewin for no one).
set -u
order=(src/base src/mesh src/geom slicer drivers src/farm src/api src/cmd)
rank() { local i; for i in "${!order[@]}"; do [ "${order[$i]}" = "$1" ] && { echo "$i"; return; }; done; echo -1; }
bad=0
while IFS= read -r f; do
  dir=$(dirname "$f")
  while IFS= read -r inc; do
    # resolve the include relative to the including file
    target=$(realpath -m --relative-to=. "$dir/$inc")
    tdir=$(dirname "$target")
    [ "$tdir" = "$dir" ] && continue
    case "$tdir" in tests*|src/base) [ "$tdir" = src/base ] && continue ;; esac
    if [ "$dir" = sim ]; then
      echo "$f: sim/ may include only src/base, not $target"; bad=1; continue
    fi
    fr=$(rank "$dir"); tr=$(rank "$tdir")
    if [ "$fr" -ge 0 ] && [ "$tr" -ge 0 ] && [ "$tr" -gt "$fr" ]; then
      echo "$f: includes $target, but $tdir comes after $dir in the layer order"; bad=1
    fi
  done < <(grep -oE '^#include "[^"]+"' "$f" | sed -E 's/#include "(.*)"/\1/')
done < <(git ls-files 'src/*' 'slicer/*' 'drivers/*' 'sim/*' | grep -E '\.(c|h|cpp)$')
[ $bad -eq 0 ] && echo "layers: ok"
exit $bad
