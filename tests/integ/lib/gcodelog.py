"""tests/integ/lib/gcodelog.py - a simulated network printer's executed log
against the G-code the farm stored for a job (farmd_bambu_crash.sh,
farmd_bambu_upload.sh, farmd_octoprint.sh).  Imported by their inline Python
(PYTHONPATH=lib), not run."""
import glob
import json
import os
import re

# the machine's own host queries (sim_netprinter.h): not the job's G-code
HOST = re.compile(r"^(M105|M110( N-?\d+)?|M400)$")


def commands(path):
    """The G-code commands of file path, comments and extra blanks gone, host queries left out."""
    out = []
    for line in open(path, errors="replace"):
        c = re.sub(r"\s+", " ", re.sub(r";.*", "", line).strip())
        if c and not HOST.match(c):
            out.append(c)
    return out


def job_gcode(tmp, name):
    """(id, commands) of the job whose API answer (GET /api/jobs/ID) is tmp/name: its stored G-code's."""
    d = json.load(open(os.path.join(tmp, name)))
    f = glob.glob(os.path.join(tmp, "data", "**", d["job"]["gcode_sha"] + "*"), recursive=True)
    return d["job"]["id"], commands(f[0])
