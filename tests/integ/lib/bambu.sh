# tests/integ/lib/bambu.sh - simulated Bambu printers for the farm
# scenarios, each behind a real mosquitto broker of its own with TLS
# (tests/bambu/env.sh: certificates from openssl, CN = serial, and a
# password file for the access code).  Sourced after lib/farm.sh, not run.
# Needs $CODE, the access code of every printer here.  Sets the EXIT trap:
# the brokers are stopped, then farm.sh's cleanup runs.
ENV=tests/bambu/env.sh
bambu_names=()

# bambu_broker_start NAME [PORT]: NAME's broker (on PORT: a restart keeps its
# port).  Sets broker_NAME (its port) and brokerpid_NAME.
bambu_broker_start() {
  local name=$1 out
  out=$($ENV broker "$tmp/$name-certs" "$CODE" ${2:+"$2"}) || fail "broker for $name"
  eval "broker_$name=${out% *} brokerpid_$name=${out#* }"
}

# bambu_broker_stop NAME: stop NAME's broker, if it runs.
bambu_broker_stop() {
  local p
  eval "p=\${brokerpid_$1:-}"
  [ -n "$p" ] && $ENV stop "$p"
  eval "brokerpid_$1="
}

bambu_cleanup() {
  local n
  for n in "${bambu_names[@]}"; do bambu_broker_stop "$n"; done
  cleanup
}
trap bambu_cleanup EXIT

# bambu_printer NAME SERIAL MODEL SPEED [SIM OPTION]...: certificates in
# $tmp/NAME-certs, a broker, and on it a simulated printer of MODEL (x1, p1)
# at SPEED, reporting every 100 ms, logging to $tmp/NAME.log (its stats line
# in $tmp/NAME.err).  Sets serial_NAME, sim_NAME (its pid), ftps_NAME, and
# mqtt_NAME: the printer's own MQTT port, in front of its broker
# (broker_NAME).  Without mosquitto or openssl the script ends here, passing
# with a note.
bambu_printer() {
  local name=$1 serial=$2 model=$3 speed=$4 rc a b
  shift 4
  $ENV certs "$tmp/$name-certs" "$serial"; rc=$?
  [ $rc -eq 77 ] && { echo "$(basename "$0" .sh): skipped (no mosquitto/openssl)"; exit 0; }
  [ $rc -eq 0 ] || fail "certificates for $name"
  bambu_names+=("$name")
  bambu_broker_start "$name"
  eval "serial_$name=$serial; b=\$broker_$name"
  "$S" bambu --serial "$serial" --access-code "$CODE" --ca "$tmp/$name-certs" --mqtt-port "$b" \
    --model "$model" --speed "$speed" --report-ms 100 --log "$tmp/$name.log" "$@" \
    > "$tmp/$name.out" 2> "$tmp/$name.err" &
  sims+=($!)
  eval "sim_$name=$!"
  for _ in $(seq 200); do [ "$(wc -l < "$tmp/$name.out")" -ge 2 ] && break; sleep 0.05; done
  a=$(sed -n 1p "$tmp/$name.out"); b=$(sed -n 2p "$tmp/$name.out")
  [ -n "$a" ] && [ -n "$b" ] || fail "sim $name did not start: $(cat "$tmp/$name.err")"
  eval "ftps_$name=${a##*:} mqtt_$name=${b##*:}"
}

# bambu_ini NAME PORT: printer NAME's section of farm.ini, reaching MQTT on PORT (its
# broker's or the printer's own), uploading to its FTPS, ejecting the part itself.
bambu_ini() {
  local serial ftps
  eval "serial=\$serial_$1 ftps=\$ftps_$1"
  printf '[printer %s]\ndriver: bambu\nurl: mqtts://127.0.0.1:%s\nserial: %s\n' "$1" "$2" "$serial"
  printf 'access_code: %s\nca_file: %s/%s-certs/ca.pem\nftps_port: %s\nauto_eject: true\n' \
    "$CODE" "$tmp" "$1" "$ftps"
}
