#!/usr/bin/env python3
"""suplayers.py A.gcode [B.gcode] - where a slicer's support is, layer by layer.

For each layer holding support: its z (mm), the filament (mm of E) under the
support roles and the box of the support moves (x0..x1 y0..y1, mm):
  z=12.20 support=0.538 x=151.40..152.10 y=102.20..107.10
then the total.  With B, the two side by side on the union of their layers
(a dash where a file prints no support), and only the layers where they
differ (filament by more than 0.01 mm or the box by more than 0.05 mm):
what one G-code supports that the other does not.  Both G-codes must come
from slices of the same placement (../shared/peers/slice-peers.sh --keep
centres every part on the bed: a result's coordinates are not the input's).

Support roles: ;TYPE:Support material[ interface] (PrusaSlicer) and
;TYPE:SUPPORT[-INTERFACE] (CuraEngine), as slice-peers.sh counts them: moves
G0-G3 with X or Y and a positive E step (E alone is a retraction or a prime);
M82/M83 and G92 E followed.  A layer is the z of its extruding moves
(PrusaSlicer prints support between the part's layers: each its own z).
Python 3 alone.
"""
import sys

ROLES = ("Support material", "Support material interface", "SUPPORT", "SUPPORT-INTERFACE")


def layers(path):
    """{z: [filament, x0, x1, y0, y1]} of the support moves of path."""
    out = {}
    rel = sup = False
    e = x = y = z = 0.0
    for line in open(path, errors="replace"):
        if line.startswith(";TYPE:"):
            sup = line[6:].strip() in ROLES
            continue
        code = line.split(";", 1)[0].split()
        if not code:
            continue
        if code[0] == "M82":
            rel = False
        elif code[0] == "M83":
            rel = True
        elif code[0] == "G92":
            e = 0.0 if len(code) == 1 else e
            for w in code[1:]:
                if w[0] == "E":
                    e = float(w[1:])
        elif code[0] in ("G0", "G1", "G2", "G3"):
            nx, ny, de, xy = x, y, None, False
            for w in code[1:]:
                if w[0] == "X":
                    nx, xy = float(w[1:]), True
                elif w[0] == "Y":
                    ny, xy = float(w[1:]), True
                elif w[0] == "Z":
                    z = float(w[1:])
                elif w[0] == "E":
                    v = float(w[1:])
                    de = v if rel else v - e
                    e = e if rel else v
            if sup and xy and de is not None and de > 0:
                k = round(z, 3)
                r = out.setdefault(k, [0.0, nx, nx, ny, ny])
                r[0] += de
                for px, py in ((x, y), (nx, ny)):
                    r[1], r[2] = min(r[1], px), max(r[2], px)
                    r[3], r[4] = min(r[3], py), max(r[4], py)
            x, y = nx, ny
    return out


def fmt(r):
    if r is None:
        return "-"
    return "support=%.3f x=%.2f..%.2f y=%.2f..%.2f" % tuple(r)


def differ(a, b):
    if a is None or b is None:
        return True
    return abs(a[0] - b[0]) > 0.01 or any(abs(p - q) > 0.05 for p, q in zip(a[1:], b[1:]))


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: suplayers.py A.gcode [B.gcode]")
    try:
        got = [layers(p) for p in sys.argv[1:]]
    except (OSError, ValueError) as ex:
        sys.exit("suplayers.py: %s" % ex)
    if len(got) == 1:
        for z in sorted(got[0]):
            print("z=%.2f %s" % (z, fmt(got[0][z])))
        print("total support=%.3f layers=%d" % (sum(r[0] for r in got[0].values()), len(got[0])))
        return
    a, b = got
    for z in sorted(set(a) | set(b)):
        if differ(a.get(z), b.get(z)):
            print("z=%.2f | %s | %s" % (z, fmt(a.get(z)), fmt(b.get(z))))
    print("total support=%.3f layers=%d | support=%.3f layers=%d"
          % (sum(r[0] for r in a.values()), len(a), sum(r[0] for r in b.values()), len(b)))


if __name__ == "__main__":
    main()
