#!/usr/bin/env bash
# 061-marlin-send-tcp: the same job over the TCP transport (a serial bridge),
# clean and with corruption, then a disconnect mid-print is reported.
. "$(dirname "$0")/lib/marlin.sh"
make_job "$TMP/job.gcode" 3000
# Faulted: 1 % of bytes garbled on the way in, and the R of one Resend on the
# way back (issue 17's reply).  Reply corruption at rates waits out execution
# times the driver computes for a printer at speed 1, so it runs on simulated
# time (test_marlin, make soak) rather than here at --speed 2000.
for faults in "" "--fault corrupt-rx=0.01 --fault seed=4 --fault bad-line=1200 --fault hit=resend:1199:0:118"; do
  # shellcheck disable=SC2086
  start_sim --tcp 0 --advanced-ok --baud 1000000 --speed 2000 --log "$TMP/log" $faults || exit 1
  case "$PORT" in tcp://127.0.0.1:*) ;; *) echo "unexpected address '$PORT'"; exit 1 ;; esac
  "$BUILD/bin/slimfarm" send "$TMP/job.gcode" --port "$PORT" --timeout-ms 250 \
    > "$TMP/send.out" 2> "$TMP/send.err" || { echo "send failed ($faults):"; tail -3 "$TMP/send.err"; exit 1; }
  stop_sim
  heads=0; [ -n "$faults" ] && heads=2
  check_log "$TMP/job.gcode" "$heads" || { echo "faults: ${faults:-none}"; exit 1; }
done
start_sim --tcp 0 --baud 1000000 --speed 2000 --fault disconnect=500 || exit 1
"$BUILD/bin/slimfarm" send "$TMP/job.gcode" --port "$PORT" --timeout-ms 250 > /dev/null 2> "$TMP/send.err" && exit 1
stop_sim
grep -q "link lost" "$TMP/send.err" || { tail -3 "$TMP/send.err"; exit 1; }
exit 0
