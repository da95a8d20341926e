# tests/integ/lib/netprint.sh - helpers for scenarios with simulated network
# printers (Moonraker, PrusaLink, OctoPrint faces of slimfarm-sim).  Sourced
# after lib/farm.sh, not run.

# start_net NAME KIND ARGS...: a simulated network printer of KIND (moonraker,
# prusalink, octoprint) logging to $tmp/NAME.log; its URL lands in $tmp/NAME.addr.
start_net() {
  local name=$1 kind=$2; shift 2
  rm -f "$tmp/$name.out" # a restarted sim must not be read from its last run's file
  "$S" "$kind" --log "$tmp/$name.log" "$@" > "$tmp/$name.out" 2> "$tmp/$name.err" &
  sims+=($!)
  eval "sim_$name=$!"
  local end=$((SECONDS + 30))
  while [ ! -s "$tmp/$name.out" ] && [ $SECONDS -lt $end ]; do sleep 0.05; done
  local a; a=$(head -n 1 "$tmp/$name.out")
  [ -n "$a" ] || fail "sim $name did not start: $(cat "$tmp/$name.err")"
  echo "$a" > "$tmp/$name.addr"
}

# check_net_logs PRINTER...: a network printer runs the file it was sent, so
# its executed log must hold, in order, each print's G-code: all of it for a
# print done, a prefix of it for one that stopped, then (cancelled) the
# printer's own cancel script (none for a print cancelled before a line of
# it ran: its upload was stopped short, and a printer never starts a file
# it did not get whole).  A print interrupted by the daemon's death and
# re-attached after it (the next print of the same job, from a start line
# past 0) is one run on the printer: the file's commands once, in full.  The
# host's M110 and M400 aside, nothing else: a job line lost, repeated or
# reordered fails.
check_net_logs() {
  fetch_jobs
  /usr/bin/python3 - "$tmp" "$@" <<'PY'
import glob, json, os, re, sys
tmp, printers = sys.argv[1], sys.argv[2:]
def commands(path):
    out = []
    for line in open(path, errors="replace"):
        c = re.sub(r"\s+", " ", re.sub(r";.*", "", line).strip())
        if c:
            out.append(c)
    return out
host = re.compile(r"^(M110( N-?\d+)?|M400)$")
cancel_script = ["M104 S0", "M140 S0", "M107", "M84"]  # sim_netprinter.h
prints = []
for f in glob.glob(os.path.join(tmp, "job-*.json")):
    d = json.load(open(f))
    for p in d["prints"]:
        prints.append((p["started_ms"], p["id"], p["printer"], p["outcome"], p.get("gcode_sha") or d["job"]["gcode_sha"],
                       d["job"]["id"], p["start_line"]))
prints.sort()
bad = 0
for name in printers:
    got = [c for c in commands(os.path.join(tmp, name + ".log")) if not host.match(c)]
    i = 0
    mine = [p for p in prints if p[2] == name]
    for k, (_, pid, _, outcome, sha, job, start) in enumerate(mine):
        if k + 1 < len(mine) and mine[k + 1][5] == job and mine[k + 1][6] > 0:
            continue  # re-attached: the next print is the rest of this very run
        files = glob.glob(os.path.join(tmp, "data", "**", sha + "*"), recursive=True)
        want = commands(files[0])
        w = 0
        while w < len(want) and i < len(got) and got[i] == want[w]:
            i += 1
            w += 1
        if outcome in ("done", "") and w != len(want):
            print("%s: print %d (job %d, %s): log line %d %r where job line %d %r was due" %
                  (name, pid, job, outcome, i + 1, got[i] if i < len(got) else None, w + 1,
                   want[w] if w < len(want) else None))
            bad += 1
            break
        if outcome == "cancelled":
            if w == 0 and got[i:i + len(cancel_script)] != cancel_script:
                continue  # cancelled before its upload was whole: the printer never ran it
            if got[i:i + len(cancel_script)] != cancel_script:
                print("%s: print %d (job %d): no cancel script after line %d: %r" %
                      (name, pid, job, w, got[i:i + 4]))
                bad += 1
                break
            i += len(cancel_script)
    if not bad and i != len(got):
        print("%s: %d log lines after the last print: %r" % (name, len(got) - i, got[i:i + 3]))
        bad += 1
    print("  %s: %d prints, %d log lines" % (name, len(mine), len(got)))
sys.exit(1 if bad else 0)
PY
}
