# tests/integ/lib/daemon.sh - start slimfarmd on a port the kernel picks
# (its config says listen: 127.0.0.1:0) and learn the port from the
# daemon's "listening on ADDRESS:PORT" log line.  A port chosen by the test
# (random, or bound and released by a helper) can be taken by another
# process before the daemon binds it; the kernel's choice cannot.  Sourced,
# not run; needs $D.

# daemon_start CONFIG LOG: start "$D" -c CONFIG, appending to LOG; once its
# "listening on" line is there, set $pid and $http_port and export
# SLIMFARM_URL.  Returns 1 when the daemon exits or says nothing for 60 s.
daemon_start() {
  local cfg=$1 log=$2 from line end=$((SECONDS + 60))
  touch "$log"
  from=$(($(stat -c %s "$log") + 1))
  "$D" -c "$cfg" >> "$log" 2>&1 &
  pid=$!
  while [ $SECONDS -lt $end ]; do
    line=$(tail -c +"$from" "$log" | grep -m 1 -o 'slimfarmd: listening on [^ ]*:[0-9]*,')
    if [ -n "$line" ]; then
      line=${line%,}
      http_port=${line##*:}
      export SLIMFARM_URL=http://127.0.0.1:$http_port
      return 0
    fi
    kill -0 "$pid" 2> /dev/null || return 1
    sleep 0.05
  done
  return 1
}
