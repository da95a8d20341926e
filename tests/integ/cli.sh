#!/usr/bin/env bash
# cli.sh - the CLI's contract: bad option values are usage errors (exit 2)
# that name the command, the option and the value; unknown profiles are
# failures (exit 1) that name the profile; a profile is found by name from
# any working directory through $SLIMFARM_CONFIG.  Env: BUILD.
set -u
build=${BUILD:-build/rel}
bin=$(realpath "$build/bin/slimfarm")
repo=$(pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fails=0
# expect STATUS PATTERN CMD...: run CMD, check its exit status and that stderr matches PATTERN
expect() {
  local want=$1 pat=$2; shift 2
  local err rc
  err=$("$@" 2>&1 >/dev/null); rc=$?
  if [ "$rc" != "$want" ] || ! grep -qE -- "$pat" <<<"$err"; then
    echo "   FAIL: $* -> exit $rc (want $want), stderr: $err"; fails=$((fails + 1))
  fi
}
"$bin" shapes "$work" >/dev/null || { echo "shapes failed"; exit 1; }
tee="$work/tee.stl"
expect 2 "slimfarm preview: --layer wants a layer number, got 'x'" "$bin" preview "$tee" -o "$work/a.png" --layer x
expect 2 "slimfarm preview: --angle wants degrees in \[0, 90\), got '95'" "$bin" preview "$tee" -o "$work/a.png" --angle 95
expect 2 "slimfarm preview: --grid wants mm in \[0.1, 20\], got '0'" "$bin" preview "$tee" -o "$work/a.png" --grid 0
expect 2 "slimfarm orient: --angle wants degrees" "$bin" orient "$tee" -o "$work/o.stl" --angle nan
expect 2 "slimfarm inspect: --up wants x,y,z \(not all zero\), got '0,0,0'" "$bin" inspect "$tee" --up 0,0,0
expect 2 "usage: slimfarm slice" "$bin" slice "$tee"
expect 2 "slimfarm: unknown command 'nosuch'" "$bin" nosuch
expect 1 "slimfarm slice: no printer profile 'nosuch'" "$bin" slice "$tee" -o "$work/t.gcode" --printer nosuch
expect 1 "slimfarm estimate: no material profile 'nosuch'" "$bin" estimate "$work/t.gcode" --material nosuch
# profiles by name from another directory, through SLIMFARM_CONFIG
(cd "$work" && SLIMFARM_CONFIG="$repo/config" "$bin" slice tee.stl -o t.gcode \
  --printer prusa-mk3s --material petg >/dev/null 2>&1) || { echo "   FAIL: slice by profile name"; fails=$((fails + 1)); }
grep -q "M104 S2[0-9][0-9]" "$work/t.gcode" 2>/dev/null || { echo "   FAIL: no nozzle temperature in t.gcode"; fails=$((fails + 1)); }
out=$(cd "$work" && SLIMFARM_CONFIG="$repo/config" "$bin" estimate t.gcode --printer prusa-mk3s --material petg 2>&1) ||
  { echo "   FAIL: estimate by profile name: $out"; fails=$((fails + 1)); }
grep -qE "^t.gcode: [0-9]+ layers" <<<"$out" || { echo "   FAIL: estimate output: $out"; fails=$((fails + 1)); }
# optimize --json reports the volume and the scale that kept it (a format slip crashed it once)
js=$("$bin" optimize "$tee" -o "$work/s.stl" --method volumetric --iterations 5 --json 2>/dev/null) &&
  grep -qE '"volume_scale": *[0-9.]+' <<<"$js" ||
  { echo "   FAIL: optimize --json: $js"; fails=$((fails + 1)); }
js=$("$bin" optimize "$tee" -o "$work/s.stl" --method volumetric --iterations 5 --no-keep-volume --json 2>/dev/null) &&
  grep -qE '"volume_scale": *1(\.0*)?[,}]' <<<"$js" ||
  { echo "   FAIL: optimize --no-keep-volume --json: $js"; fails=$((fails + 1)); }
# the front door: help comes from every command program's table; each program
# is found beside bin/ wherever the pair is installed, and loads only its own
# libraries (the reason for the split: start-up time)
out=$("$bin" help 2>&1)
for c in orient optimize slice submit watch ports preview; do
  grep -qE "^  $c +[a-z]" <<<"$out" || { echo "   FAIL: 'slimfarm help' lacks $c"; fails=$((fails + 1)); }
done
"$bin" help submit | grep -q "^usage: slimfarm submit PART" || { echo "   FAIL: help submit"; fails=$((fails + 1)); }
mkdir -p "$work/prefix/bin" "$work/prefix/libexec/slimfarm"
cp "$bin" "$work/prefix/bin/"
cp "$(dirname "$bin")/../libexec/slimfarm/slimfarm-shapes" "$work/prefix/libexec/slimfarm/"
"$work/prefix/bin/slimfarm" shapes "$work/moved" >/dev/null && [ -s "$work/moved/tee.stl" ] ||
  { echo "   FAIL: shapes through a moved install"; fails=$((fails + 1)); }
expect 1 "slimfarm orient: cannot run .*/libexec/slimfarm/slimfarm-orient" "$work/prefix/bin/slimfarm" orient "$tee" -o "$work/o.stl"
libs=$(ldd "$bin"; ldd "$(dirname "$bin")/../libexec/slimfarm/slimfarm-orient")
grep -qE "libcurl|libcairo|libcholmod|libsqlite|libzip|libcrypto|libbz2" <<<"$libs" &&
  { echo "   FAIL: slimfarm or slimfarm-orient loads libraries orient does not use"; fails=$((fails + 1)); }
# the front door runs before every command: static, no dynamic loader to start
readelf -l "$bin" | grep -q "program interpreter" &&
  { echo "   FAIL: bin/slimfarm is dynamically linked"; fails=$((fails + 1)); }
[ "$fails" -eq 0 ] && echo "   CLI errors and profile lookup as documented"
[ "$fails" -eq 0 ]
