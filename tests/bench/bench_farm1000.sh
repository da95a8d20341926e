#!/usr/bin/env bash
# tests/bench/bench_farm1000.sh BUILD - what watching a large farm of network
# printers costs: one slimfarmd with BENCH_PRINTERS (1000) printers, a
# quarter each OctoPrint, Moonraker, PrusaLink and Bambu, idle and then with
# a fifth of them (200: a twentieth of each kind) printing a long job,
# side by side in one run for the ways the daemon can watch them:
#
#   push    the defaults: OctoPrint's and Moonraker's push sockets, Bambu's
#           MQTT reports, PrusaLink polled at its state's rate (poll_ms
#           1 s while printing, poll_idle_ms 5 s while idle)
#   poll    poll_only: true on OctoPrint and Moonraker (every HTTP kind
#           polled at its state's rate)
#   poll1s  poll_only: true and poll_idle_ms: 1000: every HTTP printer
#           polled every second whatever its state, as every daemon before
#           push sockets and state rates did (issue 35: "2 HTTP requests per
#           printer per second" for OctoPrint)
#
# The printers are four simulator processes (`slimfarm-sim KIND --count N`:
# each printer a full simulated printer with its own port, sharing one
# loop), so the simulators' wake-ups do not crowd the two cores the daemon
# is measured on; the Bambu printers reach one mosquitto broker with a TLS
# listener per printer, each showing that printer's certificate (CN = its
# serial, one CA), as a printer's own broker does.  Without mosquitto or
# openssl the Bambu quarter is left out (said so) and the other kinds share
# the printers.
#
# Each mode: fresh simulators and a fresh daemon; once every printer is idle
# and BENCH_WARMUP s passed (push sockets stand), a window of BENCH_SECS s;
# then the printing jobs are uploaded as G-code (POST /api/files/local; each
# kind's printers that print answer to a printer model of their own, so the
# jobs land where they should) and, once they print and BENCH_WARMUP s
# passed, the second window.  A job is 600 one-second dwells at --speed 1:
# it prints through the window.  In each window:
#  - the daemon's CPU: utime+stime over the window from /proc/PID/stat, as a
#    share of one core; its RSS (VmRSS) at the end;
#  - per printer and second, from the simulators' counters (SIGUSR1 at both
#    ends of the window): HTTP requests the daemon made, messages pushed to
#    it (OctoPrint `current`, Moonraker `notify_status_update`, Bambu
#    reports) and, for Bambu, requests it published.
# Prints figures and the ratios of poll1s to push; never fails on them.
#
# BENCH_PRINTERS (1000; 100 for a quick look), BENCH_PRINTING (a fifth),
# BENCH_SECS (20), BENCH_WARMUP (5), BENCH_MODES ("push poll poll1s");
# DAEMON=path runs another build's slimfarmd against this build's
# simulators (before/after).
set -u
umask 077 # slimfarmd refuses a farm.ini holding keys that others can read
build=${1:-build/rel}
n=${BENCH_PRINTERS:-1000}
printing=${BENCH_PRINTING:-$((n / 5))}
secs=${BENCH_SECS:-20}
warm=${BENCH_WARMUP:-5}
modes=${BENCH_MODES:-push poll poll1s}
D=${DAEMON:-$build/bin/slimfarmd}
S=$build/bin/slimfarm-sim
for b in "$D" "$S"; do [ -x "$b" ] || { echo "bench_farm1000: $b not built"; exit 1; }; done
# 1,000 printers hold more sockets than many shells allow a process (1,024): up to the hard limit
ulimit -n "$(ulimit -Hn)" 2>/dev/null
work=$(mktemp -d)
pids=()
sim_pids=()
dpid=
mosq_pid=
stop_sims() {
  local p
  for p in "${sim_pids[@]}"; do kill "$p" 2>/dev/null; done
  for p in "${sim_pids[@]}"; do wait "$p" 2>/dev/null; done
  sim_pids=()
}
cleanup() {
  [ -n "$dpid" ] && kill "$dpid" 2>/dev/null && wait "$dpid" 2>/dev/null
  stop_sims
  [ -n "$mosq_pid" ] && kill "$mosq_pid" 2>/dev/null && wait "$mosq_pid" 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT
hz=$(getconf CLK_TCK)
key=bench-key-0123456789abcdef
code=31415926
api() { curl -sf -H "X-Api-Key: $key" "http://127.0.0.1:$port$1"; }
cpu_ticks() { awk '{ sub(/.*\) /, ""); print $12 + $13 }' "/proc/$1/stat" 2>/dev/null || echo 0; }
rss_mb() { awk '$1 == "VmRSS:" { printf "%.0f", $2 / 1024 }' "/proc/$1/status" 2>/dev/null; }
# free_port [SPAN]: the first of SPAN ports (1) that nothing listens on, below the kernel's
# ephemeral range, where the simulators' own ports (port 0) come from
free_port() {
  local lo; lo=$(cut -f1 /proc/sys/net/ipv4/ip_local_port_range 2> /dev/null || echo 32768)
  local p i
  for _ in $(seq 50); do
    p=$((10000 + RANDOM % (lo - 10000 - ${1:-1})))
    for ((i = 0; i < ${1:-1}; i++)); do (exec 3<> "/dev/tcp/127.0.0.1/$((p + i))") 2> /dev/null && break; done
    [ $i -eq "${1:-1}" ] && { echo $p; return; }
  done
  echo $p
}

# ---- the kinds and how many of each ----
kinds="op mr pl"
bambu=1
if ! [ -x /usr/sbin/mosquitto ] || ! command -v openssl > /dev/null || ! command -v mosquitto_passwd > /dev/null; then
  bambu=0
  echo "bench_farm1000: no mosquitto/openssl: Bambu printers left out"
fi
[ $bambu = 1 ] && kinds="$kinds bb"
nk=$(echo $kinds | wc -w)
declare -A count busy
i=0
for k in $kinds; do
  count[$k]=$(((n + nk - 1 - i) / nk))            # n split as evenly as it goes
  busy[$k]=$(((printing + nk - 1 - i) / nk))
  [ "${busy[$k]}" -gt "${count[$k]}" ] && busy[$k]=${count[$k]}
  [ "${count[$k]}" -gt 256 ] && { echo "bench_farm1000: at most 256 printers a kind (a simulator's --count)"; exit 1; }
  i=$((i + 1))
done

# ---- Bambu: one CA, a certificate per printer, one broker with a listener per printer ----
bb_serial=01S00BENCH
if [ $bambu = 1 ]; then
  t0=$SECONDS
  q() { "$@" > /dev/null 2>&1 || { echo "bench_farm1000: $* failed"; exit 1; }; }
  q openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -keyout "$work/ca.key" \
    -out "$work/ca.pem" -days 2 -subj "/CN=BBL CA"
  q openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -keyout "$work/printer.key" \
    -out "$work/printer.csr" -subj "/CN=unused"
  for ((i = 0; i < ${count[bb]}; i++)); do
    d=$work/bb-certs.$i
    mkdir -p "$d"
    cp "$work/ca.pem" "$work/printer.key" "$d/"
    q openssl x509 -req -in "$work/printer.csr" -CA "$work/ca.pem" -CAkey "$work/ca.key" \
      -set_serial $((i + 1)) -subj "/CN=$bb_serial$i" -out "$d/printer.pem" -days 2
  done
  chmod 644 "$work"/bb-certs.*/*
  touch "$work/passwd"
  mosquitto_passwd -b "$work/passwd" bblp "$code" > /dev/null 2>&1 || { echo "bench_farm1000: mosquitto_passwd failed"; exit 1; }
  chmod 644 "$work/passwd"
  for attempt in 1 2 3 4 5; do
    mport=$(free_port "${count[bb]}")
    {
      printf 'per_listener_settings false\nuser %s\nallow_anonymous false\npassword_file %s/passwd\n' "$(id -un)" "$work"
      printf 'persistence false\nlog_dest file %s/mosquitto.log\nlog_type error\nlog_type warning\n' "$work"
      printf 'max_connections -1\n'
      for ((i = 0; i < ${count[bb]}; i++)); do
        printf 'listener %d 127.0.0.1\ncertfile %s/bb-certs.%d/printer.pem\n' $((mport + i)) "$work" $i
        printf 'keyfile %s/bb-certs.%d/printer.key\ncafile %s/ca.pem\ntls_version tlsv1.2\n' "$work" $i "$work"
      done
    } > "$work/mosquitto.conf"
    /usr/sbin/mosquitto -c "$work/mosquitto.conf" > "$work/mosquitto.out" 2>&1 &
    mosq_pid=$!
    last=$((mport + ${count[bb]} - 1))
    for _ in $(seq 100); do
      (exec 3<> "/dev/tcp/127.0.0.1/$last") 2> /dev/null && break
      kill -0 "$mosq_pid" 2> /dev/null || break
      sleep 0.1
    done
    (exec 3<> "/dev/tcp/127.0.0.1/$last") 2> /dev/null && kill -0 "$mosq_pid" 2> /dev/null && break
    kill "$mosq_pid" 2> /dev/null; wait "$mosq_pid" 2> /dev/null; mosq_pid=
  done
  [ -n "$mosq_pid" ] || { echo "bench_farm1000: mosquitto did not start: $(cat "$work/mosquitto.log" "$work/mosquitto.out" | tail -n 3)"; exit 1; }
  echo "Bambu: ${count[bb]} certificates and a broker with ${count[bb]} TLS listeners in $((SECONDS - t0)) s"
fi

# sims_start: every kind's simulator (addresses in $work/KIND.out, one a line, two for Bambu)
sims_start() {
  local k args
  for k in $kinds; do
    case $k in
    op) args=(octoprint --count "${count[op]}" --api-key "$key") ;;
    mr) args=(moonraker --count "${count[mr]}" --api-key "$key") ;;
    pl) args=(prusalink --count "${count[pl]}" --api-key "$key") ;;
    bb) args=(bambu --count "${count[bb]}" --serial $bb_serial --access-code "$code"
      --ca "$work/bb-certs" --mqtt-port "$mport" --report-ms 1000) ;;
    esac
    "$S" "${args[@]}" > "$work/$k.out" 2> "$work/$k.err" &
    sim_pids+=($!)
    eval "sim_$k=$!"
  done
  for k in $kinds; do
    local want=${count[$k]}
    [ $k = bb ] && want=$((want * 2))
    for _ in $(seq 300); do [ "$(wc -l < "$work/$k.out")" -ge "$want" ] && break; sleep 0.1; done
    [ "$(wc -l < "$work/$k.out")" -ge "$want" ] || { echo "bench_farm1000: $k sim did not start: $(tail -3 "$work/$k.err")"; exit 1; }
  done
}

# farm_ini MODE: $work/farm.ini for the printers of sims_start, watched as MODE says
farm_ini() {
  local k i a port_ftps port_mqtt push= idle=
  case $1 in
  poll) push='poll_only: true' ;;
  poll1s) push='poll_only: true' idle='poll_idle_ms: 1000' ;;
  esac
  {
    printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data-%s\napi_keys: %s\n' "$port" "$work" "$1" "$key"
    for k in $kinds; do
      for ((i = 0; i < ${count[$k]}; i++)); do
        printf '[printer %s%d]\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 220\n' $k $i
        [ $i -lt "${busy[$k]}" ] && printf 'gcode_models: bench-%s\n' $k
        case $k in
        op | mr | pl)
          a=$(sed -n "$((i + 1))p" "$work/$k.out")
          case $k in op) printf 'driver: octoprint\n' ;; mr) printf 'driver: moonraker\n' ;; pl) printf 'driver: prusalink\n' ;; esac
          printf 'url: %s\napi_key: %s\n' "$a" "$key"
          [ $k != pl ] && [ -n "$push" ] && echo "$push"
          [ -n "$idle" ] && echo "$idle"
          ;;
        bb)
          port_ftps=$(sed -n "$((2 * i + 1))p" "$work/bb.out"); port_mqtt=$(sed -n "$((2 * i + 2))p" "$work/bb.out")
          printf 'driver: bambu\nurl: mqtts://127.0.0.1:%s\nserial: %s%d\naccess_code: %s\n' \
            "${port_mqtt##*:}" $bb_serial $i "$code"
          printf 'ca_file: %s/ca.pem\nftps_port: %s\n' "$work" "${port_ftps##*:}"
          ;;
        esac
      done
    done
  } > "$work/farm.ini"
}

# states: "IDLE PRINTING TOTAL" of the daemon's printers
states() {
  api /api/printers | /usr/bin/python3 -c '
import json, sys
p = json.load(sys.stdin)["printers"]
print(sum(x["state"] == "idle" for x in p), sum(x["state"] == "printing" for x in p), len(p))' 2> /dev/null
}

# wait_states FIELD WANT SECS: until field (1 idle, 2 printing) of states reaches WANT
wait_states() {
  local end=$((SECONDS + $3)) s
  while [ $SECONDS -lt $end ]; do
    s=$(states)
    [ -n "$s" ] && [ "$(echo "$s" | cut -d' ' -f"$1")" -ge "$2" ] && return 0
    sleep 1
  done
  echo "bench_farm1000: waited $3 s for $2 printers (field $1); states: ${s:-none}"
  return 1
}

# counters KIND: "REQUESTS PUSHED" summed over the kind's printers, from a fresh SIGUSR1
counters() {
  local k=$1 before pid want
  eval "pid=\$sim_$k"
  before=$(grep -c '^stats:' "$work/$k.err")
  want=$((before + ${count[$k]}))
  kill -USR1 "$pid"
  for _ in $(seq 200); do [ "$(grep -c '^stats:' "$work/$k.err")" -ge "$want" ] && break; sleep 0.05; done
  grep '^stats:' "$work/$k.err" | tail -n "${count[$k]}" | awk -v bb=$([ $k = bb ] && echo 1 || echo 0) '
    { for (i = 1; i <= NF; i++) { split($i, kv, "="); v[kv[1]] = kv[2] }
      if (bb) { r += v["requests"]; m += v["reports"] } else { r += v["requests"]; m += v["pushed"] } }
    END { printf "%d %d\n", r, m }'
}

# window MODE PHASE: measure one window, print its row
window() {
  local k c0 c1 t0 t1 row tot_r=0 tot_m=0
  declare -A r0 m0
  for k in $kinds; do read -r r0[$k] m0[$k] <<< "$(counters $k)"; done
  c0=$(cpu_ticks "$dpid"); t0=$(date +%s.%N)
  sleep "$secs"
  c1=$(cpu_ticks "$dpid"); t1=$(date +%s.%N)
  local wall; wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.3f", b - a }')
  local cpu; cpu=$(awk -v c=$((c1 - c0)) -v h="$hz" -v w="$wall" 'BEGIN { printf "%.1f", 100 * c / h / w }')
  row=$(printf '%-7s %-8s %6s %6s' "$1" "$2" "$cpu" "$(rss_mb "$dpid")")
  for k in $kinds; do
    read -r r m <<< "$(counters $k)"
    row="$row $(awk -v r=$((r - r0[$k])) -v m=$((m - m0[$k])) -v n="${count[$k]}" -v w="$wall" \
      'BEGIN { printf "%6.2f %6.2f", r / n / w, m / n / w }')"
    tot_r=$((tot_r + r - r0[$k])); tot_m=$((tot_m + m - m0[$k]))
  done
  row="$row $(awk -v r=$tot_r -v m=$tot_m -v n="$n" -v w="$wall" 'BEGIN { printf "%7.2f %7.2f", r / n / w, m / n / w }')"
  echo "$row" | tee -a "$work/rows"
}

# the job: 600 one-second dwells (10 min at --speed 1), one file a kind (its printer model)
for k in $kinds; do
  { printf '; printer_model = bench-%s\nG90\nM83\n' $k; for _ in $(seq 600); do printf 'G4 S1\n'; done; } > "$work/job-$k.gcode"
done

echo "$n printers ($(for k in $kinds; do printf '%s %s ' "$k" "${count[$k]}"; done| sed 's/ $//')), $printing printing; windows of $secs s after $warm s"
echo "(op OctoPrint, mr Moonraker, pl PrusaLink, bb Bambu; req/msg: HTTP requests (Bambu: MQTT requests) and pushed messages per printer per second)"
hdr=$(printf '%-7s %-8s %6s %6s' mode phase "CPU%" "RSS MB")
for k in $kinds; do hdr="$hdr $(printf '%6s %6s' "$k-req" "$k-msg")"; done
echo "$hdr $(printf '%7s %7s' all-req all-msg)"
for mode in $modes; do
  stop_sims
  sims_start
  port=$(free_port)
  farm_ini "$mode"
  "$D" -c "$work/farm.ini" > "$work/daemon-$mode.log" 2>&1 &
  dpid=$!
  t0=$SECONDS
  wait_states 1 "$n" 180 || { tail -5 "$work/daemon-$mode.log"; kill "$dpid"; wait "$dpid"; dpid=; continue; }
  sleep "$warm"
  window "$mode" idle
  for k in $kinds; do
    for ((i = 0; i < ${busy[$k]}; i++)); do
      curl -sf -o /dev/null -H "X-Api-Key: $key" -F print=true -F "file=@$work/job-$k.gcode;filename=bench-$k.gcode" \
        "http://127.0.0.1:$port/api/files/local" || echo "bench_farm1000: upload to $k refused"
    done
  done
  if ! wait_states 2 "$printing" 240; then
    got=$(states | cut -d' ' -f2)
    [ "${got:-0}" -ge $((printing * 9 / 10)) ] && echo "($mode: measured with ${got:-0} printing)"
  fi
  if [ "$(states | cut -d' ' -f2)" -ge $((printing * 9 / 10)) ]; then
    sleep "$warm"
    window "$mode" printing
  fi
  kill "$dpid"; wait "$dpid"; dpid=
done
# the ratios: today's polling (poll1s) over the defaults (push), per phase
for phase in idle printing; do
  awk -v ph=$phase '$2 == ph && $1 == "push" { c = $3; q = $(NF - 1) + $NF }
    $2 == ph && $1 == "poll1s" { c1 = $3; q1 = $(NF - 1) + $NF }
    END { if (c > 0 && q > 0 && c1 != "")
            printf "%-8s poll1s / push: daemon CPU %.1fx, requests + messages per printer %.1fx\n", ph, c1 / c, q1 / q }' \
    "$work/rows"
done
