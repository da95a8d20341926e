#!/usr/bin/env bash
# tests/integ/sim_replay_clients.sh - whole sessions of clients written by
# others replayed against the simulators (issue 35): each recorded session
# in tests/replay/clients/KIND-CLIENT.txt (the client and the version it
# follows are named in the file) runs against a fresh `slimfarm-sim KIND`
# on a port the kernel picks, and every answer's status and shape is
# checked (tests/replay/replay.py).  At least two independent clients per
# kind (OctoPrint, Moonraker, PrusaLink; Bambu's are replayed by
# sim_replay_bambu.sh).  A simulator that only answered
# what our own drivers call fails here.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
t0=$(date +%s)
dir=$(dirname "$0")/../replay
n=0
for f in "$dir"/clients/*.txt; do
  client=$(basename "$f" .txt)
  kind=${client%%-*}
  [ "$kind" = bambu ] && continue # MQTT and FTPS: sim_replay_bambu.sh
  # speed 200: a replayed print runs for a fraction of a second, enough to
  # pause, short enough to wait for its end; a session may ask for other
  # options in a "# sim-args:" line (a push session, to see a print's
  # updates go by at their real rate)
  name=${client//-/_}
  args=$(sed -n 's/^# sim-args: //p' "$f" | head -n 1)
  # shellcheck disable=SC2086
  start_net "$name" "$kind" ${args:---speed 200} --api-key replay-key
  /usr/bin/python3 "$dir/replay.py" "$(cat "$tmp/$name.addr")" replay-key "$f" ||
    fail "$client: the simulator does not answer as the client expects"
  eval "kill \$sim_$name" 2>/dev/null
  n=$((n + 1))
done
kinds=$(ls "$dir"/clients/*.txt | sed 's|.*/||; s|-.*||' | sort | uniq -c | awk '$1 < 2 { print $2 }')
[ -z "$kinds" ] || fail "fewer than two clients for: $kinds"
echo "sim_replay_clients: $n client sessions ok in $(( $(date +%s) - t0 )) s"
