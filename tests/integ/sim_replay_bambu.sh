#!/usr/bin/env bash
# tests/integ/sim_replay_bambu.sh - whole sessions of Bambu LAN clients
# written by others replayed against the Bambu simulator (issue 35): each
# tests/replay/clients/bambu-CLIENT.txt (the client and the version it
# follows are named in the file) runs through tests/replay/bambu_replay.py,
# MQTT 3.1.1 over TLS to the printer's broker (a real mosquitto,
# tests/bambu/env.sh) and implicit FTPS to its storage, and every reply's
# code and report's shape is checked.  At least two independent clients.
# Without mosquitto or openssl it passes with a note (lib/bambu.sh).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
CODE=31415926
. "$(dirname "$0")/lib/bambu.sh"
t0=$(date +%s)
dir=$(dirname "$0")/../replay
bambu_printer rp 01S00X1000000009 x1 200
n=0
for f in "$dir"/clients/bambu-*.txt; do
  /usr/bin/python3 "$dir/bambu_replay.py" 127.0.0.1 "$mqtt_rp" "$ftps_rp" "$serial_rp" "$CODE" "$f" ||
    fail "$(basename "$f" .txt): the simulator does not answer as the client expects"
  n=$((n + 1))
done
[ $n -ge 2 ] || fail "fewer than two Bambu clients ($n)"
echo "sim_replay_bambu: $n client sessions ok in $(( $(date +%s) - t0 )) s"
