#!/usr/bin/env bash
# tests/bench/soak.sh BUILD - `make soak`: the long runs make check cannot
# afford (issue 17).  Not part of make check or make bench.
# 1. bench_soak: SOAK_PRINTS (1000) prints of a 3000-line part through the
#    Marlin driver to a simulated stock Marlin 2 (plain ok, BUFSIZE 4, RX 128
#    on a UART) with 1 % of bytes garbled each way and 1 % of oks lost, on
#    simulated time; the printer's executed log judges each print (every
#    command once, in order).  Prints recovery time per print.
# 2. farmd_crash_print.sh with SOAK_KILLS (100) kill -9 of slimfarmd at
#    random moments while four simulated printers print: every job exists
#    once and ends done, resumed or restarted.
# 3. policy_soak.sh: SOAK_FILES (200) G-code files carrying random G-code
#    policy rows, uploaded to four simulated printers: each is refused
#    naming its lines, or prints once with no line lost or repeated.
# Exit 1 if any fails.
set -u
build=${1:-build/rel}
rc=0
echo "=== soak: prints"
"$build/bench/bench_soak" --prints "${SOAK_PRINTS:-1000}" --lines 3000 --corrupt 0.01 \
  --drop-ok 0.01 || rc=1
echo "=== soak: slimfarmd killed ${SOAK_KILLS:-100} times while 4 printers print"
kills=${SOAK_KILLS:-100}
BUILD=$build ROUNDS=$kills PRINTERS=4 bash tests/integ/farmd_crash_print.sh || rc=1
echo "=== soak: ${SOAK_FILES:-200} files with random G-code policy rows, 4 printers"
BUILD=$build N=${SOAK_FILES:-200} bash tests/bench/policy_soak.sh || rc=1
exit $rc
