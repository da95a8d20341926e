#!/usr/bin/env bash
# tests/integ/farmd_crash_print.sh - slimfarmd killed with SIGKILL 10 times
# at random moments while two simulated Marlins print (one on a pty, which
# resets when the restarted daemon reopens it, like a USB board on DTR;
# one behind TCP, which only sees the disconnect).  After each kill: the
# store passes --fsck; after each restart every submitted job is there
# exactly once, nothing is printing that was not started anew, the jobs
# that were printing are interrupted (or done, when the daemon logged the
# print's end between the test's snapshot and the kill) with their last acknowledged line
# (never behind what the API showed before the kill) on their print
# record too, and the operator resumes each from that line (restart when
# no line or every line was acknowledged).  At the end every job is done
# and each printer's executed log is consistent: an interrupted print's
# lines up to (at least) its acknowledged line, then the resume preamble
# and the job's lines from there (lib/farm.sh check_farm_logs).
# ROUNDS (default 10) and PRINTERS (2 or 4: a second pair, default 2) let
# `make soak` (tests/bench/soak.sh) run the same test at length; jobs are
# added as the rounds use them up (JOB_GROUPS: groups of four to begin with).
set -u
BUILD=${BUILD:-build/san}
ROUNDS=${ROUNDS:-10}
names="usb net"
[ "${PRINTERS:-2}" = 4 ] && names="usb net usb2 net2"
. "$(dirname "$0")/lib/farm.sh"
t0=$(date +%s)

# 250 kbaud: a few thousand lines a second, so prints last long enough to kill.
for p in $names; do
  case $p in usb*) start_sim "$p" --baud 250000 --speed 2000 ;; *) start_sim "$p" --baud 250000 --speed 2000 --tcp 0 ;; esac
done
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  for p in $names; do
    printf '[printer %s]\ndriver: marlin\nport: %s\nbaud: 250000\nmaterial: PLA\nauto_eject: true\n' \
      "$p" "$(cat "$tmp/$p.addr")"
  done
} > "$tmp/farm.ini"
start_daemon
wait_for 20 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq $(echo $names | wc -w) ]" || fail "printers: $("$C" printers)"
"$C" shapes "$tmp" > /dev/null || fail "shapes"
tetra "$tmp/t12.stl" 12
tetra "$tmp/t15.stl" 15
ids=
submit_group() { # four jobs, one of each part
  for part in lbracket tee t12 t15; do
    ids="$ids $(submit "$tmp/$part.stl" --material PLA --method none)"
  done
}
# JOB_GROUPS (default 1) groups of four jobs to begin with, and a group
# more before a round whenever fewer jobs wait than there are printers: so
# every kill finds prints, and the end waits only for those few, however
# many jobs the rounds get through (that depends on how long a print takes
# against a round, which the machine's load decides)
for _ in $(seq "${JOB_GROUPS:-1}"); do submit_group; done
n_printers=$(echo $names | wc -w)
n_waiting() { api_jobs | json 'sum(j["state"] in ("queued", "preparing", "ready") for j in d["jobs"])'; }

snapshot() { # id state lines_acked, one job a line
  api_jobs | json '"\n".join("%d %s %d" % (j["id"], j["state"], j["lines_acked"]) for j in d["jobs"])'
}
resumed=0 restarted=0 interrupted=0 finished=0
for round in $(seq "$ROUNDS"); do
  [ "$(n_waiting)" -ge "$n_printers" ] || submit_group
  wait_for 60 sh -c "'$C' jobs | grep -q ' printing '" || break # all printed already
  sleep "$((RANDOM % 2)).$((RANDOM % 10))"
  logpos=$(stat -c %s "$tmp/log")
  snapshot > "$tmp/before"
  kill -9 $pid; wait $pid 2>/dev/null; pid=
  tail -c +"$((logpos + 1))" "$tmp/log" > "$tmp/between" # what it logged from the snapshot to the kill
  out=$("$D" -c "$tmp/farm.ini" --fsck 2>&1) || fail "round $round: fsck: $out"
  start_daemon
  snapshot > "$tmp/after"
  [ "$(cut -d' ' -f1 "$tmp/after" | sort -n | tr '\n' ' ')" = "$(echo $ids | tr ' ' '\n' | sort -n | tr '\n' ' ')" ] ||
    fail "round $round: jobs lost or duplicated: $(cat "$tmp/after")"
  while read -r id state acked; do
    read -r _ now lines < <(grep "^$id " "$tmp/after")
    case "$state" in
      printing|paused)
        if [ "$now" = done ]; then # it may have finished between the snapshot and the kill
          read -r pr outcome < <(api "/api/jobs/$id" | json 'd["prints"][-1]["printer"] + " " + d["prints"][-1]["outcome"]')
          [ "$outcome" = done ] || fail "round $round: job $id is done, its last print: $outcome"
          grep -q "printer\[$pr\]: printing -> idle" "$tmp/between" ||
            fail "round $round: job $id was $state, now done, but $pr did not finish it before the kill"
          finished=$((finished + 1))
          continue
        fi
        [ "$now" = interrupted ] || fail "round $round: job $id was $state, now $now"
        [ "$lines" -ge "$acked" ] || fail "round $round: job $id came back at line $lines, the API showed $acked"
        last=$(api "/api/jobs/$id" | json 'd["prints"][-1]["outcome"] + " " + str(d["prints"][-1]["lines_acked"])')
        "$C" jobs | grep -qE "^$id +interrupted +[0-9]+/[0-9]+ +$lines/[0-9]+ " ||
          fail "round $round: jobs does not show job $id's line $lines: $("$C" jobs)"
        [ "$last" = "interrupted $lines" ] || fail "round $round: job $id's last print: $last (job says $lines)"
        interrupted=$((interrupted + 1))
        ;;
      done|interrupted) [ "$now" = "$state" ] || fail "round $round: job $id was $state, now $now" ;;
    esac
  done < "$tmp/before"
  # printing now: only a job the restarted daemon started anew (it was waiting before the kill)
  while read -r id now _; do
    case "$now" in printing|paused) ;; *) continue ;; esac
    read -r _ was _ < <(grep "^$id " "$tmp/before")
    case "$was" in printing|paused|interrupted|done|failed|cancelled)
      fail "round $round: job $id was $was before the kill, $now right after recovery" ;;
    esac
  done < "$tmp/after"
  # the operator resumes every interrupted job once its printer is back
  for id in $(awk '$2 == "interrupted" { print $1 }' "$tmp/after"); do
    pr=$(api "/api/jobs/$id" | json 'd["job"]["printer"]')
    wait_for 20 sh -c "'$C' printers | grep -qE '^$pr +idle'" || fail "round $round: $pr not back: $("$C" printers)"
    lines=$(grep "^$id " "$tmp/after" | cut -d' ' -f3)
    if [ "$round" = 1 ]; then # a line past the job's end is refused, saying the range
      out=$("$C" resume-job "$id" --line 99999999 2>&1) && fail "resumed past the end"
      [[ "$out" == *"409: job $id: line 99999999 is out of range: resume from 1.."* ]] || fail "range: $out"
    fi
    if out=$("$C" resume-job "$id" 2>&1); then
      [ "$out" = "job $id: printing on $pr from line $lines" ] || fail "round $round: resume-job said: $out"
      resumed=$((resumed + 1))
    else
      [[ "$out" == *"is out of range"* ]] || fail "round $round: resume-job $id: $out"
      "$C" restart "$id" > /dev/null || fail "restart $id"
      restarted=$((restarted + 1))
    fi
  done
  echo "  round $round: $(tr '\n' ',' < "$tmp/after")"
done
[ "$interrupted" -ge 5 ] || fail "only $interrupted prints were interrupted by $ROUNDS kills"
[ "$resumed" -ge 3 ] || fail "only $resumed resumed"
# every job ends done: fail only when none ends for 240 s, however many are left
n_done() { api_jobs | json 'sum(j["state"] == "done" for j in d["jobs"])'; }
n_jobs=$(echo $ids | wc -w)
more_done() { local n; n=$(n_done); [ "$n" -gt "$1" ] || [ "$n" -eq "$n_jobs" ]; }
while [ "$(n_done)" -lt "$n_jobs" ]; do
  wait_for 240 more_done "$(n_done)" || fail "not all done, none ended in 240 s: $("$C" jobs)"
done
# a resume is refused for a job that is not interrupted, and for a line out of range
out=$("$C" resume-job 1 2>&1) && fail "resumed a done job"
[[ "$out" == *"409: job 1 is done: only an interrupted job can be resumed"* ]] || fail "resume done: $out"
stop_sims
check_farm_logs $names || fail "executed logs are not consistent with the jobs"
kill -TERM $pid; wait $pid; pid=
echo "farmd_crash_print: ok ($ROUNDS kills, $n_printers printers, $n_jobs jobs, $interrupted prints interrupted, $resumed resumed, $restarted restarted, $finished finished just before a kill, $(( $(date +%s) - t0 )) s)"
