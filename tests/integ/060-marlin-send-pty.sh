#!/usr/bin/env bash
# 060-marlin-send-pty: `slimfarm send` streams 3000 lines to slimfarm-sim over
# a pty, on a clean link and with 1% of bytes corrupted on the way in; the
# simulator's executed log must equal the job's commands exactly.
. "$(dirname "$0")/lib/marlin.sh"
make_job "$TMP/job.gcode" 3000
# Faulted: 1 % of bytes garbled on the way in, and the R of one Resend on the
# way back (issue 17's reply).  Reply corruption at rates waits out execution
# times the driver computes for a printer at speed 1, so it runs on simulated
# time (test_marlin, make soak) rather than here at --speed 2000.
for faults in "" "--fault corrupt-rx=0.01 --fault seed=21 --fault bad-line=1200 --fault hit=resend:1199:0:118"; do
  # shellcheck disable=SC2086
  start_sim --advanced-ok --baud 1000000 --speed 2000 --log "$TMP/log" $faults || exit 1
  "$BUILD/bin/slimfarm" send "$TMP/job.gcode" --port "pty:$PORT" --baud 1000000 --timeout-ms 250 \
    > "$TMP/send.out" 2> "$TMP/send.err" || { echo "send failed ($faults):"; tail -3 "$TMP/send.err"; exit 1; }
  stop_sim
  want=$(commands "$TMP/job.gcode" | wc -l)
  grep -q "lines=$want acked=$want " "$TMP/send.out" || { echo "send summary: $(cat "$TMP/send.out")"; exit 1; }
  heads=0; [ -n "$faults" ] && heads=2
  check_log "$TMP/job.gcode" "$heads" || { echo "faults: ${faults:-none}"; exit 1; }
done
# A bad port is a clear error, not a hang.
"$BUILD/bin/slimfarm" send "$TMP/job.gcode" --port pty:/nonexistent 2> "$TMP/err" && exit 1
grep -q "nonexistent" "$TMP/err" || { cat "$TMP/err"; exit 1; }
exit 0
