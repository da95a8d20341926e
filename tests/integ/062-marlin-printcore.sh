#!/usr/bin/env bash
# 062-marlin-printcore: the simulator is a printer, not a mirror of our
# driver.  Printrun's printcore (Debian printrun-common; it imports only
# under /usr/bin/python3) prints a job through it with its own numbered
# ping-pong protocol, and a bare host sends unnumbered lines and waits for
# each "ok".  Both logs must equal the job.
. "$(dirname "$0")/lib/marlin.sh"
make_job "$TMP/job.gcode" 1500
if ! /usr/bin/python3 -c 'import printrun.printcore' 2> /dev/null; then
  echo "printrun is not installed (make deps installs printrun-common)"; exit 1
fi
start_sim --baud 1000000 --speed 2000 --log "$TMP/log" || exit 1
/usr/bin/python3 - "$PORT" "$TMP/job.gcode" <<'PY' 2> "$TMP/pc.err" || { cat "$TMP/pc.err"; exit 1; }
import sys, time
from printrun.printcore import printcore
from printrun import gcoder
p = printcore(sys.argv[1], 115200)
t0 = time.time()
while not p.online and time.time() - t0 < 10:
    time.sleep(0.05)
if not p.online:
    sys.exit("printcore: printer never came online")
p.startprint(gcoder.LightGCode([l.rstrip("\n") for l in open(sys.argv[2])]))
t0 = time.time()
while p.printing and time.time() - t0 < 60:
    time.sleep(0.05)
done = not p.printing
p.disconnect()
sys.exit(0 if done else "printcore: print did not finish")
PY
stop_sim
check_log "$TMP/job.gcode" || exit 1

# A bare host: plain lines, no numbers, one "ok" at a time.
start_sim --baud 1000000 --speed 2000 --log "$TMP/log" || exit 1
/usr/bin/python3 - "$PORT" "$TMP/job.gcode" <<'PY' || exit 1
import os, select, sys, tty, time
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
tty.setraw(fd)
buf = b""
def wait_ok(timeout):
    global buf
    end = time.time() + timeout
    while True:
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            if line.startswith(b"ok"):
                return True
        left = end - time.time()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            return False
        buf += os.read(fd, 4096)
# Like any host: say hello until the printer (maybe still booting) answers.
for _ in range(20):
    os.write(fd, b"M105\n")
    if wait_ok(0.5):
        break
else:
    sys.exit("bare host: printer never answered")
for raw in open(sys.argv[2]):
    cmd = raw.split(";")[0].strip()
    if cmd:
        os.write(fd, cmd.encode() + b"\n")
        if not wait_ok(5):
            sys.exit("bare host: no ok for " + cmd)
os.close(fd)
PY
stop_sim
check_log "$TMP/job.gcode" || exit 1
exit 0
