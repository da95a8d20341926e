#!/usr/bin/env bash
# cli.sh - the CLI's contract: bad option values are usage errors (exit 2)
# that name the command, the option and the value; unknown profiles are
# failures (exit 1) that name the profile; a profile is found by name from
# any working directory through $SLIMFARM_CONFIG; every program and command
# answers -h/--help with its usage on stdout and exit 0; each command program
# links only the libraries its commands use.  Env: BUILD.
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
# the direction search's --json says per direction where its shape step
# started and, when it kept the shape, why; the axes it weighed unreshaped
# are listed after the reshaped directions, with no iterations (issue 36)
js=$("$bin" optimize "$tee" -o "$work/d.stl" --method surface --search-direction 2 --iterations 5 \
  --json 2>/dev/null) && python3 -c 'import json, sys
d = json.load(sys.stdin)["search"]["directions"]
assert len(d) >= 1
for x in d:
    assert x["start_model_g"] >= x["model_support_g"] - 1e-9, x
    assert x["iterations"] == 0 if x["axis"] else x["iterations"] >= 1, x
    assert ("unchanged_why" in x) != x["shape_changed"], x' <<<"$js" ||
  { echo "   FAIL: optimize --search-direction --json: $js"; fails=$((fails + 1)); }
# the front door: help comes from every command program's table; each program
# is found beside bin/ wherever the pair is installed, and loads only its own
# libraries (the reason for the split: start-up time)
out=$("$bin" help 2>&1)
for c in orient optimize slice submit watch ports preview; do
  grep -qE "^  $c +[a-z]" <<<"$out" || { echo "   FAIL: 'slimfarm help' lacks $c"; fails=$((fails + 1)); }
done
"$bin" help submit | grep -q "^usage: slimfarm submit PART" || { echo "   FAIL: help submit"; fails=$((fails + 1)); }
# the help names every option a command takes (it once left out send's
# --window and --timeout-ms, submit's all but three, the farm commands' --url)
for w in "send:--window N" "send:--timeout-ms N" "submit:--method none|orient|slim|surface" \
  "submit:--group G" "submit:--retries N" "preview:--size WxH"; do
  "$bin" help "${w%%:*}" | grep -qF -- "${w#*:}" || { echo "   FAIL: help ${w%%:*} lacks ${w#*:}"; fails=$((fails + 1)); }
done
grep -qF -- "take --url URL and --key KEY" <<<"$out" || { echo "   FAIL: 'slimfarm help' does not say how to reach the daemon"; fails=$((fails + 1)); }
mkdir -p "$work/prefix/bin" "$work/prefix/libexec/slimfarm"
cp "$bin" "$work/prefix/bin/"
cp "$(dirname "$bin")/../libexec/slimfarm/slimfarm-shapes" "$work/prefix/libexec/slimfarm/"
"$work/prefix/bin/slimfarm" shapes "$work/moved" >/dev/null && [ -s "$work/moved/tee.stl" ] ||
  { echo "   FAIL: shapes through a moved install"; fails=$((fails + 1)); }
expect 1 "slimfarm orient: cannot run .*/libexec/slimfarm/slimfarm-orient" "$work/prefix/bin/slimfarm" orient "$tee" -o "$work/o.stl"
# -h and --help: the usage on stdout, nothing on stderr, exit 0, for the front
# door, every command (the list 'slimfarm help' prints), the daemon and the
# simulator
help_ok() { # CMD...: its stdout starts with $want
  local out err rc
  out=$("$@" 2>"$work/help.err"); rc=$?; err=$(cat "$work/help.err")
  if [ "$rc" != 0 ] || [ -n "$err" ] || [ "${out#"$want"}" = "$out" ]; then
    echo "   FAIL: $* -> exit $rc, stdout '${out%%$'\n'*}', stderr '$err' (want '$want...')"; fails=$((fails + 1))
  fi
}
cmds=$("$bin" help | sed -n 's/^  \([a-z][a-z-]*\) .*/\1/p')
[ "$(wc -w <<<"$cmds")" -ge 15 ] || { echo "   FAIL: 'slimfarm help' lists only: $cmds"; fails=$((fails + 1)); }
for h in -h --help; do
  want="usage: slimfarm COMMAND"; help_ok "$bin" $h
  for c in $cmds; do
    want="usage: slimfarm $c"; help_ok "$bin" "$c" $h
  done
  want="usage: slimfarm send"; help_ok "$bin" send "$work/t.gcode" --port pty:/nonexistent $h
  want="usage: slimfarmd"; help_ok "$(dirname "$bin")/slimfarmd" $h
  want="usage: slimfarm-sim"; help_ok "$(dirname "$bin")/slimfarm-sim" $h
  want="usage: slimfarm-sim"; help_ok "$(dirname "$bin")/slimfarm-sim" marlin $h
done
"$bin" optimize --help | grep -q "^       slimfarm optimize PART -o OUT --method surface" ||
  { echo "   FAIL: optimize --help lacks the surface form"; fails=$((fails + 1)); }
# after "--" it is an operand, not a request for help
expect 1 "slimfarm inspect: .*--help" "$bin" inspect -- --help
# Each command program links (DT_NEEDED) only the libraries its commands use:
# a helper that needs a library lives apart (cmdprofile.c, cmdreport.c), so
# e.g. JSON or the INI parser never ride along into shapes, send or ports.
# Base libraries (libc, libm, libstdc++, libgcc_s, sanitizer runtimes) aside.
declare -A may=(
  [estimate]="inih polyclipping minizip expat embree3"
  [farm]="curl jansson"
  [inspect]="jansson minizip expat embree3"
  [optimize]="qhull_r jansson minizip expat embree3 tet cholmod"
  [orient]="qhull_r jansson minizip expat embree3"
  [hosts]="sqlite3 pq jansson crypto"
  [ports]="serialport"
  [preview]="inih minizip expat cairo embree3"
  [send]="serialport"
  [shapes]="minizip expat"
  [slice]="inih polyclipping minizip expat embree3"
)
for prog in "$(dirname "$bin")"/../libexec/slimfarm/slimfarm-*; do
  m=${prog##*/slimfarm-}
  [ -n "${may[$m]+x}" ] || { echo "   FAIL: no library list for slimfarm-$m in cli.sh"; fails=$((fails + 1)); continue; }
  for lib in $(readelf -d "$prog" | sed -n 's/.*Shared library: \[lib\([^].]*\)\..*/\1/p'); do
    case " c m stdc++ gcc_s pthread asan ubsan tsan ${may[$m]} " in
    *" $lib "*) ;;
    *) echo "   FAIL: slimfarm-$m links lib$lib, which its commands do not use"; fails=$((fails + 1)) ;;
    esac
  done
done
ldd "$bin" | grep -q "=>" && { echo "   FAIL: bin/slimfarm loads shared libraries"; fails=$((fails + 1)); }
# the front door runs before every command: static, no dynamic loader to start
readelf -l "$bin" | grep -q "program interpreter" &&
  { echo "   FAIL: bin/slimfarm is dynamically linked"; fails=$((fails + 1)); }
[ "$fails" -eq 0 ] && echo "   CLI errors and profile lookup as documented"
[ "$fails" -eq 0 ]
