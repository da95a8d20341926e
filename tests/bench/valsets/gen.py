#!/usr/bin/env python3
"""gen.py - generates the validation sets' parts with OpenSCAD's CLI.

  gen.py mech OUTDIR [NAME...]   the mech family: PARTS below, each a template
                                 of mech/ with parameters drawn from SEED
  gen.py scad OUTDIR [NAME...]   OpenSCAD's shipped examples (SCAD_EXAMPLES)
  gen.py list mech|scad          the part names, one a line

Every part is written as a binary STL, OUTDIR/NAME.stl, resting on z = 0 and
centred on the peers' bed (125, 105), in the orientation it was modelled in
(the template's `rot`: some parts are uploaded the awkward way, as users do:
a lid lip-down, a bracket on its side).  OUTDIR/params.txt records every
part's drawn parameters.  Called by tests/bench/valsets.sh, which keeps
the results in a cache keyed by the templates' content; never committed.

The mech parameters come from one fixed seed (VALSET_SEED, default 14), one
random stream per part (seeded by SEED:NAME), so adding a part leaves the
others as they were.  The family is measured on, never tuned on: change a
range or a template only for a reason that holds for every part, and say
it in the commit.

The scad set: the examples in Debian's openscad package
(/usr/share/openscad/examples), licence CC0-1.0 (debian/copyright:
"Files: examples/*  Copyright: 2013 Clifford Wolf, Andrew Plumb, Nathan
Hellweg, Emmett Lalish and Marius Kintel  License: CC0-1.0").  The ones
that are one printable solid and need support in some orientation (the
list says how they were chosen), exported as OpenSCAD renders them, one
scaled down to fit the size range.
"""
import os
import random
import struct
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = "/usr/share/openscad/examples"
BED = (125.0, 105.0)
SEED = os.environ.get("VALSET_SEED", "14")

# name, template, rot, parameters: (lo, hi) a uniform draw rounded to 0.1 mm,
# (lo, hi, "int") an integer, a plain number fixed, ("from", PART, KEY) the
# value drawn for another part (a lid that fits its box).
PARTS = [
    ("box_open", "box", [0, 0, 0], dict(L=(50, 110), W=(35, 80), H=(20, 45), wall=(1.2, 3), floor_t=(1.2, 2),
                                        r=(2, 6), lip_h=(2, 4), snap=1, ears=0, vents=0)),
    ("lid_up", "lid", [0, 0, 0], dict(L=("from", "box_open", "L"), W=("from", "box_open", "W"),
                                      r=("from", "box_open", "r"), wall=("from", "box_open", "wall"),
                                      t=(1.2, 3), lip_h=(2, 4), lip_w=(1.2, 2), snap=1, recess=1)),
    ("enclosure", "box", [0, 0, 0], dict(L=(70, 98), W=(45, 80), H=(25, 45), wall=(1.6, 3), floor_t=(1.2, 2.4),
                                         r=(2, 6), lip_h=(2, 4), snap=1, ears=1, vents=(2, 4, "int"),
                                         vent_w=(8, 16), vent_h=(2, 4))),
    ("lid_down", "lid", [180, 0, 0], dict(L=("from", "enclosure", "L"), W=("from", "enclosure", "W"),
                                          r=("from", "enclosure", "r"), wall=("from", "enclosure", "wall"),
                                          t=(1.2, 3), lip_h=(2, 4), lip_w=(1.2, 2), snap=1, recess=1)),
    ("box_upside", "box", [180, 0, 0], dict(L=(40, 80), W=(30, 60), H=(15, 30), wall=(1.2, 2.4), floor_t=(1.2, 2),
                                            r=(2, 5), lip_h=(2, 3), snap=0, ears=0, vents=0)),
    ("plate_standoffs", "standoff_plate", [0, 0, 0], dict(L=(50, 110), W=(40, 80), t=(1.6, 3), sh=(5, 14), sd=(6, 9),
                                                          hole=(2.5, 3.4), nx=(2, 3, "int"), ny=2, r=(2, 5), slot=1)),
    ("boss_block", "boss_block", [0, 0, 0], dict(L=(40, 90), W=(30, 60), t=(2, 4), n=(2, 4, "int"), bd=(7, 12),
                                                 bh=(8, 18), hole=(2.5, 4), wall_h=(18, 35), hb_d=(8, 14),
                                                 hb_len=(0.2, 0.35))),
    ("bracket_side", "bracket", [90, 0, 0], dict(a=(30, 80), b=(30, 70), t=(3, 6), w=(24, 40), ng=(1, 2, "int"),
                                                 g=(0.4, 0.8), hole=(3.4, 5.5))),
    ("bracket_up", "bracket", [0, 0, 0], dict(a=(30, 80), b=(30, 70), t=(3, 6), w=(24, 40), ng=(1, 2, "int"),
                                              g=(0.4, 0.8), hole=(3.4, 5.5))),
    ("bore_round", "bore_block", [0, 0, 0], dict(L=(28, 45), W=(16, 30), d=(8, 22), H=(14, 26), base_t=(4, 8),
                                                 teardrop=0, hole=(3.4, 5.5), cross_d=(3, 5))),
    ("bore_teardrop", "bore_block", [0, 0, 0], dict(L=(28, 45), W=(16, 30), d=(8, 22), H=(14, 26), base_t=(4, 8),
                                                    teardrop=1, hole=(3.4, 5.5), cross_d=(3, 5))),
    ("slot_bridge", "slot_bridge", [0, 0, 0], dict(L=(50, 110), W=(12, 30), n=(2, 4, "int"), s0=(4, 8), s1=(12, 30),
                                                   sh=(4, 10), t=(1.6, 3), foot=(3, 5))),
    ("hook", "hook", [0, 0, 0], dict(ph=(40, 90), t=(3, 6), w=(12, 25), reach=(20, 45), tip=(8, 20), r_in=(3, 8),
                                     hole=(3.5, 5), arm_z=(0.15, 0.4))),
    ("clip", "clip", [0, 90, 0], dict(D=(12, 32), t=(1.6, 3), w=(8, 20), open=(80, 120), tab=(6, 12),
                                     tab_t=(2, 4), hole=(3, 3.6))),
    ("shelf", "shelf", [0, 0, 0], dict(L=(60, 120), depth=(25, 60), back_h=(30, 60), t=(2.4, 4), nb=(2, 3, "int"),
                                       lip=(3, 6), hole=(3.5, 5))),
    ("thread_side", "thread_boss", [90, 0, 0], dict(D=(10, 24), p=(1.5, 3), h=(12, 30), flange=(12, 24),
                                                    ft=(3, 6), bore=(0.2, 0.45), hole=(3, 3.6))),
]
# relative draws: RELATIVE adds the named parameter's value to the draw (the
# pillow block's height and length grow with its bore, the flange with its
# stud), FRACTION multiplies by it (the stud's bore, the side boss's length)
RELATIVE = {("bore_block", "H"): "d", ("bore_block", "L"): "d", ("thread_boss", "flange"): "D"}
FRACTION = {("thread_boss", "bore"): "D", ("boss_block", "hb_len"): "W"}

# example file (under EXAMPLES), longest side in mm (None: as modelled).
# Chosen from all 40 examples: the ones OpenSCAD 2021.01 renders as one
# closed solid of 20-120 mm (example005, 240 mm, scaled to 100) that need
# support as modelled or turned; left out: 2D or failing ones, several
# solids (CSG, children, example017-021, rotate_extrude ...), flat plates
# needing none (example010, 011, 019, surface_image, LetterBlock, offset),
# those under 1 g of support (example007, 009, 014).
SCAD_EXAMPLES = [
    ("Old/example001.scad", None),
    ("Old/example002.scad", None),
    ("Old/example003.scad", None),
    ("Old/example004.scad", None),
    ("Old/example005.scad", 100),
    ("Old/example006.scad", None),
    ("Old/example008.scad", None),
    ("Old/example012.scad", None),
    ("Old/example013.scad", None),
    ("Old/example016.scad", None),
    ("Basics/logo.scad", None),
    ("Basics/text_on_cube.scad", None),
]


def draw(parts):
    """{name: (template, rot, {key: value})} for every part, from SEED."""
    out = {}
    for name, tpl, rot, spec in parts:
        rng = random.Random("%s:%s" % (SEED, name))
        vals = {}
        for key in sorted(spec):
            s = spec[key]
            if isinstance(s, tuple) and s[0] == "from":
                v = out[s[1]][2][s[2]]
            elif isinstance(s, tuple) and len(s) == 3:
                v = rng.randint(s[0], s[1])
            elif isinstance(s, tuple):
                v = round(rng.uniform(s[0], s[1]), 1)
            else:
                v = s
            vals[key] = v
        for (t, key), base in RELATIVE.items():
            if t == tpl and key in vals:
                vals[key] = round(vals[key] + vals[base], 1)
        for (t, key), base in FRACTION.items():
            if t == tpl and key in vals:
                vals[key] = round(vals[key] * vals[base], 1)
        out[name] = (tpl, rot, vals)
    return out


def read_stl(path):
    """triangles [(v0, v1, v2)] of an ASCII or binary STL"""
    raw = open(path, "rb").read()
    if raw[:5] == b"solid" and b"facet" in raw[:400]:
        vs = [tuple(float(x) for x in ln.split()[1:4]) for ln in raw.decode().splitlines()
              if ln.strip().startswith("vertex")]
        return [tuple(vs[i:i + 3]) for i in range(0, len(vs) - 2, 3)]
    n = struct.unpack_from("<I", raw, 80)[0]
    tris = []
    for i in range(n):
        f = struct.unpack_from("<12f", raw, 84 + 50 * i)
        tris.append((f[3:6], f[6:9], f[9:12]))
    return tris


def write_stl(path, tris, scale=1.0):
    """binary STL, scaled about the origin, dropped on z = 0, centred on BED"""
    lo = [min(v[k] for t in tris for v in t) * scale for k in range(3)]
    hi = [max(v[k] for t in tris for v in t) * scale for k in range(3)]
    off = (BED[0] - (lo[0] + hi[0]) / 2, BED[1] - (lo[1] + hi[1]) / 2, -lo[2])
    buf = [b"slimfarm valsets".ljust(80, b" "), struct.pack("<I", len(tris))]
    for t in tris:
        p = [[v[k] * scale + off[k] for k in range(3)] for v in t]
        a = [p[1][k] - p[0][k] for k in range(3)]
        b = [p[2][k] - p[0][k] for k in range(3)]
        n = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
        ln = sum(x * x for x in n) ** 0.5 or 1.0
        buf.append(struct.pack("<12fH", *(x / ln for x in n), *p[0], *p[1], *p[2], 0))
    tmp = path + ".tmp"
    with open(tmp, "wb") as fh:
        fh.write(b"".join(buf))
    os.replace(tmp, path)
    return [h - l for l, h in zip(lo, hi)]


def openscad(src, out, defs, cwd):
    args = ["openscad", "-o", out]
    for k, v in defs.items():
        args += ["-D", "%s=%s" % (k, v)]
    r = subprocess.run(args + [src], cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0 or not os.path.exists(out):
        sys.exit("gen.py: openscad failed on %s: %s" % (src, r.stderr.strip().splitlines()[-1:]))


def gen_mech(outdir, names):
    parts = draw(PARTS)
    with open(os.path.join(outdir, "params.txt"), "a") as log:
        for name, (tpl, rot, vals) in parts.items():
            if names and name not in names:
                continue
            tmp = os.path.join(outdir, name + ".ascii.stl")
            defs = dict(vals, rot="[%g,%g,%g]" % tuple(rot))
            openscad(os.path.join(HERE, "mech", tpl + ".scad"), tmp, defs, os.path.join(HERE, "mech"))
            size = write_stl(os.path.join(outdir, name + ".stl"), read_stl(tmp))
            os.remove(tmp)
            log.write("%s %s %s size %.1f x %.1f x %.1f\n" % (name, tpl, " ".join(
                "%s=%s" % kv for kv in sorted(defs.items())), *size))


def gen_scad(outdir, names):
    with open(os.path.join(outdir, "params.txt"), "a") as log:
        for rel, longest in SCAD_EXAMPLES:
            name = os.path.splitext(os.path.basename(rel))[0]
            if names and name not in names:
                continue
            src = os.path.join(EXAMPLES, rel)
            tmp = os.path.join(outdir, name + ".ascii.stl")
            openscad(src, tmp, {}, os.path.dirname(src))
            tris = read_stl(tmp)
            ext = max(max(v[k] for t in tris for v in t) - min(v[k] for t in tris for v in t) for k in range(3))
            scale = longest / ext if longest else 1.0
            size = write_stl(os.path.join(outdir, name + ".stl"), tris, scale)
            os.remove(tmp)
            log.write("%s %s scale %.4g size %.1f x %.1f x %.1f\n" % (name, rel, scale, *size))


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "list":
        names = [p[0] for p in PARTS] if sys.argv[2] == "mech" else \
            [os.path.splitext(os.path.basename(e[0]))[0] for e in SCAD_EXAMPLES]
        print("\n".join(names))
        return
    if len(sys.argv) < 3 or sys.argv[1] not in ("mech", "scad"):
        sys.exit("usage: gen.py mech|scad OUTDIR [NAME...] | gen.py list mech|scad")
    outdir = os.path.abspath(sys.argv[2])  # openscad runs in the template's folder
    os.makedirs(outdir, exist_ok=True)
    (gen_mech if sys.argv[1] == "mech" else gen_scad)(outdir, set(sys.argv[3:]))


if __name__ == "__main__":
    main()
