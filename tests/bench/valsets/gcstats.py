#!/usr/bin/env python3
"""gcstats.py FILE.gcode - what a G-code prints, by role, for bench_slice.sh.

Prints one line of key=value pairs:
  perim ext gap infill solid bridge support iface other  filament mm (E) under
      each ;TYPE: role (the words PrusaSlicer 2.5 writes, which our gcwrite.c
      writes too): perim = Perimeter, ext = External perimeter + Overhang
      perimeter, solid = Solid infill + Top solid infill, infill = Internal
      infill, bridge = Bridge infill, gap = Gap fill, support = Support
      material, iface = Support material interface, other = the rest
  walls   the length of all perimeter loops over that of the external ones,
      over all layers: a loop is a run of extruding moves of the perimeter
      roles between two moves that do not extrude, that ends within 1 mm of
      where it started and is over 3 mm long (open runs, thin-wall fragments,
      are not loops); a loop holding External perimeter (or only Overhang
      perimeter) is external.  2.00: every contour has two perimeters all
      round (by length, so a few small loops in a thin wall's corners do not
      count as a second perimeter along it).
  top bottom  the solid skin's thickness in mm over and under sparse infill:
      the parts are rastered on a 1 mm grid, each layer's cells marked by what
      is extruded there (solid, sparse infill, anything else); in every
      column, a run of solid layers with the part's sparse interior on one
      side and the outside of the part on the other is a top (outside above)
      or bottom (outside below) skin; the median run, in layers times the
      layer height.  Outside is where the cell's centre lies outside the
      layer's external perimeter loops (even-odd), or past the first or last
      layer: air, or support.  The sparse interior is a cell of sparse infill,
      or an empty cell inside those loops (15 % infill leaves most 1 mm cells
      between its lines empty).  Judged by the cell below being empty
      instead, as this once did, a solid run over a gap between sparse lines
      counted as a bottom (dino: the solid under its head's sloping top, 4
      to 8 layers depending on which slicer's infill lines crossed the cell)
      and a bottom over support never counted (support marks the cell).
      "-" without such runs.
  layers  the part's layer count (distinct z of extrusion other than support,
      which PrusaSlicer may print between the part's layers)
Extrusion follows M82/M83 and G92 E; G2/G3 arcs are measured along the arc.
Python 3 alone (no numpy): make check has no numpy.
"""
import math
import re
import statistics
import sys

ROLE = {"Perimeter": "perim", "External perimeter": "ext", "Overhang perimeter": "ext",
        "Internal infill": "infill", "Solid infill": "solid", "Top solid infill": "solid",
        "Bridge infill": "bridge", "Gap fill": "gap", "Support material": "support",
        "Support material interface": "iface"}
KEYS = ["perim", "ext", "gap", "infill", "solid", "bridge", "support", "iface", "other"]
WORD = re.compile(r"([A-Z])(-?[0-9.]+)")
CELL = 1.0  # mm, the raster for the skin thickness


def arc_points(x0, y0, x1, y1, i, j, cw):
    """points along a G2 (cw) / G3 arc from (x0, y0) to (x1, y1), centre
    (x0 + i, y0 + j), every 0.5 mm or less; and the arc's length"""
    cx, cy = x0 + i, y0 + j
    r = math.hypot(i, j)
    a0 = math.atan2(y0 - cy, x0 - cx)
    a1 = math.atan2(y1 - cy, x1 - cx)
    sweep = a1 - a0
    if cw and sweep >= 0:
        sweep -= 2 * math.pi
    if not cw and sweep <= 0:
        sweep += 2 * math.pi
    length = abs(sweep) * r
    n = max(1, int(length / 0.5))
    return [(cx + r * math.cos(a0 + sweep * k / n), cy + r * math.sin(a0 + sweep * k / n)) for k in range(1, n + 1)], length


def main():
    mm = dict.fromkeys(KEYS, 0.0)
    relative = False
    e = 0.0
    x = y = z = 0.0
    role = "other"
    roleword = ""
    run = None  # the perimeter run being extruded: set of roles seen
    loops = ext_loops = 0.0  # mm of closed perimeter loops, of external ones
    cells = {}  # (layer z, cx, cy) -> "s" solid, "i" infill, "o" other
    zs = set()

    run_from = run_to = (0.0, 0.0)
    run_len = 0.0
    run_pts = []
    run_z = 0.0
    outlines = {}  # layer z -> the external perimeter loops' points

    def end_run():
        nonlocal run, loops, ext_loops
        closed = math.hypot(run_to[0] - run_from[0], run_to[1] - run_from[1]) < 1.0 and run_len > 3.0
        if run and closed:
            loops += run_len
            if "External perimeter" in run or run == {"Overhang perimeter"}:
                ext_loops += run_len
                outlines.setdefault(run_z, []).append(run_pts)
        run = None

    def mark(pts, zk):
        kind = "s" if role in ("solid", "bridge") else "i" if role == "infill" else "o"
        for px, py in pts:
            key = (zk, int(math.floor(px / CELL)), int(math.floor(py / CELL)))
            old = cells.get(key)
            if old is None or (old != "o" and kind == "o") or (old == "i" and kind == "s"):
                cells[key] = kind

    for line in open(sys.argv[1], errors="replace"):
        if line.startswith(";TYPE:"):
            roleword = line[6:].strip()
            role = ROLE.get(roleword, "other")
            continue
        code = line.split(";", 1)[0].strip()
        if not code:
            continue
        head = code.split(None, 1)[0]
        if head == "M82":
            relative = False
        elif head == "M83":
            relative = True
        elif head == "G92":
            w = dict(WORD.findall(code))
            if "E" in w:
                e = float(w["E"])
        elif head in ("G0", "G1", "G2", "G3"):
            w = dict(WORD.findall(code))
            nx, ny = float(w.get("X", x)), float(w.get("Y", y))
            if "Z" in w:
                z = float(w["Z"])
            de = 0.0
            if "E" in w:
                ev = float(w["E"])
                de = ev if relative else ev - e
                e = e + ev if relative else ev
            moved = nx != x or ny != y
            if de > 0 and moved:
                mm[role] += de
                zk = round(z, 2)
                if role not in ("support", "iface"):
                    zs.add(zk)  # the part's layers (support may print between them)
                if head in ("G2", "G3"):
                    pts, arc_len = arc_points(x, y, nx, ny, float(w.get("I", 0)), float(w.get("J", 0)), head == "G2")
                else:
                    d = math.hypot(nx - x, ny - y)
                    n = max(1, int(d / 0.5))
                    pts = [(x + (nx - x) * k / n, y + (ny - y) * k / n) for k in range(n + 1)]
                mark(pts, zk)
                if role in ("perim", "ext"):
                    if not run:
                        run, run_from, run_len, run_pts, run_z = set(), (x, y), 0.0, [(x, y)], zk
                    run.add(roleword)
                    run_pts.extend(pts[1:] if head in ("G0", "G1") else pts)
                    run_to = (nx, ny)
                    run_len += arc_len if head in ("G2", "G3") else math.hypot(nx - x, ny - y)
                else:
                    end_run()
            elif moved:
                end_run()
            x, y = nx, ny
    end_run()

    layers = sorted(zs)
    height = statistics.median([b - a for a, b in zip(layers, layers[1:])]) if len(layers) > 1 else 0.2
    index = {zk: k for k, zk in enumerate(layers)}
    cols = {}
    for (zk, cx, cy), kind in cells.items():
        if zk in index:
            cols.setdefault((cx, cy), {})[index[zk]] = kind
    rows = {}  # (layer, cell row) -> the outlines' crossings of the row's centre line

    def inside(k, cx, cy):
        """is the centre of cell (cx, cy) inside layer k's outlines?"""
        if k < 0 or k >= len(layers):
            return False
        key = (k, cy)
        if key not in rows:
            yc = (cy + 0.5) * CELL
            xs = []
            for loop in outlines.get(layers[k], []):
                for (ax, ay), (bx, by) in zip(loop, loop[1:] + loop[:1]):
                    if (ay > yc) != (by > yc):
                        xs.append(ax + (bx - ax) * (yc - ay) / (by - ay))
            rows[key] = sorted(xs)
        xc = (cx + 0.5) * CELL
        return sum(1 for x in rows[key] if x < xc) % 2 == 1

    top, bottom = [], []
    for (cx, cy), col in cols.items():
        k = 0
        last = max(col)
        while k <= last:
            if col.get(k) != "s":
                k += 1
                continue
            s = k
            while col.get(k) == "s":
                k += 1
            below, above = col.get(s - 1), col.get(k)
            sparse_below = below == "i" or (below is None and inside(s - 1, cx, cy))
            sparse_above = above == "i" or (above is None and inside(k, cx, cy))
            if sparse_below and not inside(k, cx, cy):
                top.append(k - s)
            elif sparse_above and not inside(s - 1, cx, cy):
                bottom.append(k - s)
    walls = "%.2f" % (loops / ext_loops) if ext_loops else "-"
    th = [("%.2f" % (statistics.median(v) * height)) if v else "-" for v in (top, bottom)]
    print(" ".join("%s=%.1f" % (k, mm[k]) for k in KEYS),
          "walls=%s top=%s bottom=%s layers=%d" % (walls, th[0], th[1], len(layers)))


if __name__ == "__main__":
    main()
