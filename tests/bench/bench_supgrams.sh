#!/usr/bin/env bash
# bench_supgrams.sh BUILD - the peers' verdict on the optimizers: for every
# mesh of the sets asked for, the part as given, oriented (slimfarm orient),
# surface optimized (optimize --method surface) and oriented then
# volumetrically slimmed (orient + optimize --method volumetric, as the
# farm's --method slim does) and the direction search with surface
# optimization inside (optimize --method surface --search-direction 4; its
# seconds are wall time), each sliced by PrusaSlicer and CuraEngine
# (../shared/peers, 45 deg, supports on): support grams and their print-time
# estimate, with the layer-based model's grams (supmodel.h), our optimizers'
# seconds and MNDR/ANDR, and our own slicer's support grams.  Peer rows are
# cached by the STL's md5 under build/peercache/stl (peers run under nice -n
# 19: a shared machine).
# SUPGRAMS_SET picks the sets (tests/bench/valsets.sh): shared (default, the
# tuning set), mech, scad, or several ("mech scad", all).  Each set's rows
# end with its totals per variant against the part as given (PrusaSlicer and
# CuraEngine support grams, PrusaSlicer's estimated time, ours, each with its
# % change; the parts whose support rose in either peer beyond 2 % + 0.05 g
# of slicer noise, those printing over 2 % slower, those unchanged (the same
# STL, or grams within 0.5 % + 0.02 g in both peers; a part that needs no
# support as given is counted apart, as none), the largest MNDR and
# ANDR), over the parts where both rows have figures
# (tests/bench/valsets/totals.awk); with more than one set a last table puts
# the sets' % changes side by side.
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
[ -d "$shared/peers" ] || { echo "bench_supgrams: $shared/peers absent, skipped"; exit 0; }
peers="$(cd "$shared" && pwd)/peers/slice-peers.sh"
# shellcheck disable=SC2086
meshes=$("$(dirname "$0")/valsets.sh" ${SUPGRAMS_SET:-shared})
[ -n "$meshes" ] || { echo "bench_supgrams: no meshes in set ${SUPGRAMS_SET:-shared}, skipped"; exit 0; }
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
# totals SET: its rows summed per variant over the parts where the variant
# and the part as given both have the figure, with the % change
totals() {
  awk -v set="$1" -v vars="$variants" -f "$(dirname "$0")/valsets/totals.awk" "$rows"
}
# side_by_side: every set's % changes against the part as given, per variant
side_by_side() {
  awk -v vars="$variants" -v side=1 -f "$(dirname "$0")/valsets/totals.awk" "$rows"
}
one_dir=$(mktemp); echo "0 0 0 1" > "$one_dir"
rows=$(mktemp) # set mesh variant PS_g PS_s CE_g CE_s ours_g mndr% andr% md5, for the totals
trap 'rm -f "$one_dir" "$rows"' EXIT
header() {
  printf '%-17s %-8s | %8s %8s | %8s %8s | %8s %8s | %7s %7s %8s | %8s\n' mesh variant PS_g PS_h CE_g CE_h \
    model_PS model_CE MNDR% ANDR% opt_s ours_g
}
prev_set=
while IFS=$'\t' read -r set f; do
  name=$(basename "$f" .stl)
  [ -n "${SUPGRAMS_MESHES:-}" ] && [[ " $SUPGRAMS_MESHES " != *" $name "* ]] && continue
  if [ "$set" != "$prev_set" ]; then
    [ -n "$prev_set" ] && totals "$prev_set"
    echo "== set $set"; header; prev_set=$set
  fi
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
    cols="" raw=""
    for s in prusaslicer curaengine; do
      if [[ " $slicers " == *" $s "* ]]; then read -r g t < <(peer "$out" "$s"); else g=- t=-; fi
      cols="$cols $g $(awk -v t="$t" 'BEGIN { if (t + 0 > 0) printf "%.2f", t / 3600; else print "-" }')"
      raw="$raw $g ${t:--}"
    done
    pm=$(awk -v x="$mndr" 'BEGIN { if (x == "-") print "-"; else printf "%.2f", 100 * x }')
    pa=$(awk -v x="$andr" 'BEGIN { if (x == "-") print "-"; else printf "%.2f", 100 * x }')
    # shellcheck disable=SC2086
    printf '%-17s %-8s | %8s %8s | %8s %8s | %8s %8s | %7s %7s %8s | %8s\n' $row $cols "$mps" "$mce" \
      "$pm" "$pa" "$(awk -v x="$secs" 'BEGIN { if (x == "-") print "-"; else printf "%.1f", x }')" "$ours"
    echo "$set $name $v$raw $ours $pm $pa $(md5sum < "$out" | cut -c1-32)" >> "$rows"
  done
done <<< "$meshes"
[ -n "$prev_set" ] && totals "$prev_set"
[ "$(cut -d' ' -f1 "$rows" | sort -u | wc -l)" -gt 1 ] && side_by_side
