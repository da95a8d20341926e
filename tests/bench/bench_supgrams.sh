#!/usr/bin/env bash
# bench_supgrams.sh BUILD - the peers' verdict on the optimizers: for every
# shared mesh, the part as given, oriented (slimfarm orient), surface
# optimized (optimize --method surface) and oriented then volumetrically
# slimmed (orient + optimize --method volumetric, as the farm's --method slim
# does) and the direction search with surface optimization inside
# (optimize --method surface --search-direction 4; its seconds are wall time), each sliced by PrusaSlicer and CuraEngine (../shared/peers, 45 deg,
# supports on): support grams and their print-time estimate, with the layer-
# based model's grams (supmodel.h), our optimizers' seconds and MNDR/ANDR,
# and our own slicer's support grams.  Peer rows are cached by the STL's md5
# under build/peercache/stl (peers run under nice -n 19: a shared machine).
# SUPGRAMS_MESHES="anchor dino" limits the meshes; SUPGRAMS_VARIANTS (default
# "given orient surface slim search"); SUPGRAMS_PEERS (default "prusaslicer curaengine");
# SUPGRAMS_CACHED_ONLY=1 reports cached peer rows only (a dash where none is).
# The optimized variants depend on this tree's code: they are kept under
# SUPGRAMS_OUT (default build/supgrams/ plus the first 8 hex of the md5 of
# the CLI and its libexec commands, so a rebuilt optimizer makes its own),
# while the peer rows,
# keyed by content, may be shared between trees (PEER_CACHE).
set -u
build=${1:-build/rel}
shared=${SLIMFARM_SHARED:-../shared}
[ -d "$shared/meshes" ] || { echo "bench_supgrams: $shared/meshes absent, skipped"; exit 0; }
peers="$(cd "$shared" && pwd)/peers/slice-peers.sh"
cache=${PEER_CACHE:-build/peercache}
sf="$build/bin/slimfarm"
# the CLI runs its commands from libexec: the key covers them all
vdir=${SUPGRAMS_OUT:-build/supgrams/$(cat "$sf" "$build"/libexec/slimfarm/* 2>/dev/null | md5sum | cut -c1-8)}
mkdir -p "$cache/stl" "$vdir"
variants=${SUPGRAMS_VARIANTS:-given orient surface slim search}
slicers=${SUPGRAMS_PEERS:-prusaslicer curaengine}
py=/usr/bin/python3
jget() { "$py" -c 'import json,sys
d=json.load(open(sys.argv[1]))
for k in sys.argv[2].split("."): d=d[k]
print(d)' "$1" "$2" 2>/dev/null || echo -; }
# peer FILE SLICER -> "support_g est_time_s" (cached by content)
peer() {
  local sum row; sum=$(md5sum < "$1" | cut -c1-32); row="$cache/stl/$sum.$2.csv"
  if [ ! -s "$row" ] && [ -z "${SUPGRAMS_CACHED_ONLY:-}" ]; then
    PEER_RUNS=$2:on PEER_TIMEOUT=${PEER_TIMEOUT:-900} nice -n 19 "$peers" "$1" --format csv > "$row.tmp" 2>/dev/null && mv "$row.tmp" "$row"
  fi
  awk -F, 'NR == 2 { print ($8 == 0 ? $14 " " $15 : "fail -") }' "$row" 2>/dev/null || echo "- -"
}
one_dir=$(mktemp); echo "0 0 0 1" > "$one_dir"; trap 'rm -f "$one_dir"' EXIT
printf '%-17s %-8s | %8s %8s | %8s %8s | %8s %8s | %7s %7s %8s | %8s\n' mesh variant PS_g PS_h CE_g CE_h \
  model_PS model_CE MNDR% ANDR% opt_s ours_g
for f in $(ls -S -r "$shared"/meshes/*.stl); do
  name=$(basename "$f" .stl)
  [ -n "${SUPGRAMS_MESHES:-}" ] && [[ " $SUPGRAMS_MESHES " != *" $name "* ]] && continue
  for v in $variants; do
    out="$vdir/$name-$v.stl" js="$vdir/$name-$v.json"
    mndr=- andr=- secs=-
    case $v in
      given) out=$f ;;
      orient) [ -s "$js" ] || nice "$sf" orient "$f" -o "$out" --json > "$js" || continue
              secs=$(jget "$js" seconds) ;;
      surface) [ -s "$js" ] || nice "$sf" optimize "$f" -o "$out" --method surface --json > "$js" || continue
               secs=$(jget "$js" seconds.total) mndr=$(jget "$js" deviation.mndr) andr=$(jget "$js" deviation.andr) ;;
      slim) o="$vdir/$name-orient.stl"
            [ -s "$o" ] || nice "$sf" orient "$f" -o "$o" --json > "$vdir/$name-orient.json" || continue
            [ -s "$js" ] || nice "$sf" optimize "$o" -o "$out" --method volumetric --json > "$js" || continue
            secs=$(jget "$js" seconds) mndr=$(jget "$js" deviation.mndr) andr=$(jget "$js" deviation.andr) ;;
      search) [ -s "$js" ] || { /usr/bin/time -f %e -o "$js.time" nice "$sf" optimize "$f" -o "$out" --method surface \
                 --search-direction 4 --json > "$js" || continue; }
              secs=$(cat "$js.time" 2>/dev/null || echo -) mndr=$(jget "$js" deviation.mndr) andr=$(jget "$js" deviation.andr) ;;
    esac
    [ -s "$out" ] || continue
    read -r mps mce _ < <("$build/bench/bench_supmodel" "$out" "$one_dir" | awk 'NR == 1 { print $2, $3 }')
    ours=$(nice "$sf" slice "$out" -o "$vdir/$name-$v.gcode" 2>/dev/null |
      sed -n 's/.*(support \([0-9.]*\) g).*/\1/p')
    ours=${ours:--}
    row="$name $v"
    cols=""
    for s in prusaslicer curaengine; do
      if [[ " $slicers " == *" $s "* ]]; then read -r g t < <(peer "$out" "$s"); else g=- t=-; fi
      cols="$cols $g $(awk -v t="$t" 'BEGIN { if (t + 0 > 0) printf "%.2f", t / 3600; else print "-" }')"
    done
    # shellcheck disable=SC2086
    printf '%-17s %-8s | %8s %8s | %8s %8s | %8s %8s | %7s %7s %8s | %8s\n' $row $cols "$mps" "$mce" \
      "$(awk -v x="$mndr" 'BEGIN { if (x == "-") print "-"; else printf "%.2f", 100 * x }')" \
      "$(awk -v x="$andr" 'BEGIN { if (x == "-") print "-"; else printf "%.2f", 100 * x }')" \
      "$(awk -v x="$secs" 'BEGIN { if (x == "-") print "-"; else printf "%.1f", x }')" "$ours"
  done
done
