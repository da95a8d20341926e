#!/usr/bin/env bash
# tests/bambu/env.sh - the real components a Bambu printer puts in a
# client's way, for the Bambu tests: certificates made with openssl and
# Debian's mosquitto broker with a TLS listener and a password file.
#
#   env.sh certs DIR SERIAL      DIR/ca.pem ca.key printer.pem printer.key (CN=SERIAL, signed by
#                                the CA, X.509 v1 with no SAN as on an X1), DIR/other-ca.pem, and
#                                DIR/other-printer.pem/.key (CN=01S00OTHER00000, the same CA:
#                                another printer's, for the simulator's ftps-wrong-cert fault)
#   env.sh broker DIR CODE [PORT] start mosquitto in the background: TLS 1.2 on 127.0.0.1:PORT
#                                (a free one when not given) presenting printer.pem, user bblp
#                                with password CODE; prints "PORT PID" once it listens
#   env.sh stop PID              stop that broker
# Exits 77 when mosquitto or openssl is missing (callers skip).
set -u
cmd=${1:?usage: env.sh certs|broker|stop ...}
MOSQ=/usr/sbin/mosquitto
have() { [ -x "$MOSQ" ] && command -v openssl >/dev/null && command -v mosquitto_passwd >/dev/null; }
case $cmd in
certs)
  dir=$2 serial=$3
  have || exit 77
  mkdir -p "$dir"
  q() { "$@" >/dev/null 2>&1 || { echo "env.sh: $* failed" >&2; exit 1; }; }
  q openssl req -x509 -newkey rsa:2048 -nodes -keyout "$dir/ca.key" -out "$dir/ca.pem" -days 30 -subj "/CN=BBL CA"
  q openssl req -newkey rsa:2048 -nodes -keyout "$dir/printer.key" -out "$dir/printer.csr" -subj "/CN=$serial"
  q openssl x509 -req -in "$dir/printer.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" -CAcreateserial \
      -out "$dir/printer.pem" -days 30
  q openssl req -x509 -newkey rsa:2048 -nodes -keyout "$dir/other-ca.key" -out "$dir/other-ca.pem" -days 30 \
      -subj "/CN=Someone else's CA"
  q openssl req -newkey rsa:2048 -nodes -keyout "$dir/other-printer.key" -out "$dir/other-printer.csr" \
      -subj "/CN=01S00OTHER00000"
  q openssl x509 -req -in "$dir/other-printer.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" -CAcreateserial \
      -out "$dir/other-printer.pem" -days 30
  chmod 644 "$dir"/*.pem "$dir"/*.key
  ;;
broker)
  dir=$2 code=$3 want=${4:-}
  have || exit 77
  rm -f "$dir/passwd"; touch "$dir/passwd"
  mosquitto_passwd -b "$dir/passwd" bblp "$code" >/dev/null 2>&1 || { echo "env.sh: mosquitto_passwd failed" >&2; exit 1; }
  chmod 644 "$dir/passwd"
  for attempt in 1 2 3 4 5 6 7 8; do
    port=${want:-$((20000 + RANDOM % 30000))}
    cat > "$dir/mosquitto.conf" <<CONF
per_listener_settings false
user $(id -un)
allow_anonymous false
password_file $dir/passwd
persistence false
log_dest file $dir/mosquitto.log
log_type error
log_type warning
log_type notice
log_type information
listener $port 127.0.0.1
certfile $dir/printer.pem
keyfile $dir/printer.key
cafile $dir/ca.pem
tls_version tlsv1.2
CONF
    : > "$dir/mosquitto.log"
    "$MOSQ" -c "$dir/mosquitto.conf" >/dev/null 2>&1 &
    pid=$!
    for i in $(seq 1 100); do
      if grep -q "Opening ipv4 listen socket on port $port" "$dir/mosquitto.log" 2>/dev/null &&
         (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null; then
        echo "$port $pid"; exit 0
      fi
      kill -0 "$pid" 2>/dev/null || break
      sleep 0.05
    done
    kill "$pid" 2>/dev/null; wait "$pid" 2>/dev/null
    [ -n "$want" ] && sleep 0.2   # a fixed port (a restart): wait for it to be free
  done
  echo "env.sh: mosquitto did not start: $(tail -3 "$dir/mosquitto.log")" >&2; exit 1
  ;;
stop)
  kill "$2" 2>/dev/null
  for i in $(seq 1 100); do kill -0 "$2" 2>/dev/null || exit 0; sleep 0.05; done
  kill -9 "$2" 2>/dev/null; exit 0
  ;;
*) echo "env.sh: unknown command $cmd" >&2; exit 2 ;;
esac
