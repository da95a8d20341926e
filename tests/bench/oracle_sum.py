#!/usr/bin/python3
"""oracle_sum.py ROWS - bench_oracle.sh's per-part choices and per-set totals.

ROWS has one "set part tag ux uy uz PS_g PS_s model_g model_s" line a
candidate ("-" where a figure is missing); tag "+z" is the part as given,
"search" the direction search's (reshaped) result.  See bench_oracle.sh for
the choices (given, search, ps_g, ps_t, mod_g, mod_t)."""
import sys

SLOW = 0.02          # "not slower than given": within 2 %
NOISE_REL, NOISE_G = 0.02, 0.05  # PrusaSlicer's noise on grams


def num(x):
    return None if x == "-" else float(x)


def same_g(a, b):
    return abs(a - b) <= NOISE_REL * max(a, b) + NOISE_G


def same_t(a, b):
    return abs(a - b) <= SLOW * max(a, b)


parts = {}  # (set, part) -> {tag: (psg, pss, mg, ms)}
order = []
for line in open(sys.argv[1]):
    f = line.split()
    if len(f) < 10:
        continue
    key = (f[0], f[1])
    if key not in parts:
        parts[key] = {}
        order.append(key)
    parts[key][f[2]] = tuple(num(x) for x in f[6:10])


def best_g(c, gi, ti, lim):
    """Least grams (index gi) among c whose seconds (ti) are within lim; ties: faster."""
    ok = [t for t in c if c[t][gi] is not None and c[t][ti] is not None and c[t][ti] <= lim]
    return min(ok, key=lambda t: (round(c[t][gi], 2), c[t][ti])) if ok else None


def fastest(c, ti, gi):
    ok = [t for t in c if c[t][ti] is not None and c[t][gi] is not None]
    return min(ok, key=lambda t: (c[t][ti], c[t][gi])) if ok else None


choices = ("given", "search", "ps_g", "ps_t", "mod_g", "mod_t", "mod_v", "srch_v", "ps_gx")
GRAM_S = 60  # printtime_policy_default: a gram of support is worth 60 print seconds


def best_value(c):
    """The search's own rule without reshaping (dirsearch_pick): among the
    candidates that need no more model grams and no more model seconds than
    given, the least seconds + GRAM_S * grams."""
    g0, s0 = c["+z"][2], c["+z"][3]
    ok = [t for t in c if c[t][2] <= g0 and c[t][3] <= s0]
    return min(ok, key=lambda t: c[t][3] + GRAM_S * c[t][2])
by_set, mis = {}, []
print("\n%-14s | %-16s | %-16s | %-19s | %-19s | %-19s | %-19s" %
      ("part", "given g/h", "search g/h", "ps_g dir g/h", "ps_t dir g/h", "mod_g dir g/h ok", "mod_t dir g/h ok"))
for key in order:
    s, p = key
    all_c = parts[key]
    # the candidates PrusaSlicer sliced (both choosers pick among these)
    c = {t: v for t, v in all_c.items() if t != "search" and v[0] is not None and v[1] is not None}
    if "+z" not in c or c["+z"][0] is None or c["+z"][1] is None:
        print("%-14s | no PrusaSlicer row as given" % p)
        continue
    g0, t0 = c["+z"][0], c["+z"][1]
    pick = {"given": "+z", "ps_g": best_g(c, 0, 1, (1 + SLOW) * t0), "ps_t": fastest(c, 1, 0),
            "ps_gx": best_g(c, 0, 1, float("inf"))}
    if "search" in all_c and all_c["search"][0] is not None and all_c["search"][1] is not None:
        pick["search"] = "search"
    if all(v[2] is not None and v[3] is not None for v in c.values()):
        pick["mod_g"] = best_g(c, 2, 3, (1 + SLOW) * c["+z"][3])
        pick["mod_t"] = fastest(c, 3, 2)
        pick["mod_v"] = best_value(c)
        # the search with these candidates among its results: the lesser value by the model
        sr = all_c.get("search")
        if pick.get("search") and sr[2] is not None and sr[3] is not None:
            v = c[pick["mod_v"]]
            pick["srch_v"] = "search" if sr[3] + GRAM_S * sr[2] <= v[3] + GRAM_S * v[2] else pick["mod_v"]
    ok_g = ok_t = None
    if pick.get("mod_g"):
        a, b = c[pick["mod_g"]], c[pick["ps_g"]]
        ok_g = pick["mod_g"] == pick["ps_g"] or (same_g(a[0], b[0]) and a[1] <= (1 + SLOW) * t0)
    if pick.get("mod_t"):
        a, b = c[pick["mod_t"]], c[pick["ps_t"]]
        ok_t = pick["mod_t"] == pick["ps_t"] or same_t(a[1], b[1])
    row = by_set.setdefault(s, {"n": 0, "unchanged": 0, "mis_g": 0, "mis_t": 0, "missing": [],
                                **{ch: [0, 0.0, 0.0, 0.0, 0.0] for ch in choices}})
    # each choice summed over the parts where it has figures, against given there
    row["n"] += 1
    row["unchanged"] += pick["ps_g"] == "+z"
    for ch in choices:
        if pick.get(ch) is None:
            row["missing"].append("%s:%s" % (ch, p))
            continue
        v = all_c[pick[ch]]
        row[ch] = [row[ch][0] + 1, row[ch][1] + v[0], row[ch][2] + v[1], row[ch][3] + g0, row[ch][4] + t0]
        # worse than given by PrusaSlicer: more grams beyond its noise, or over 2 % slower
        if v[0] > g0 * (1 + NOISE_REL) + NOISE_G or v[1] > (1 + SLOW) * t0:
            row.setdefault("worse_" + ch, []).append(p)
    row["mis_g"] += ok_g is False
    row["mis_t"] += ok_t is False

    def cell(ch, flag=None):
        t = pick.get(ch)
        if t is None:
            return "-"
        v = all_c[t]
        txt = "%.2f/%.2f" % (v[0], v[1] / 3600)
        if ch not in ("given", "search"):
            txt = "%-3s %s" % (t, txt)
        if flag is not None:
            txt += " " + ("y" if flag else "N")
        return txt
    print("%-14s | %-16s | %-16s | %-19s | %-19s | %-19s | %-19s" % (
        p, cell("given"), cell("search"), cell("ps_g"), cell("ps_t"), cell("mod_g", ok_g), cell("mod_t", ok_t)))
    for what, ok, mine, theirs in (("grams", ok_g, pick.get("mod_g"), pick["ps_g"]),
                                   ("time", ok_t, pick.get("mod_t"), pick["ps_t"])):
        if ok is False:
            a, b = c[mine], c[theirs]
            mis.append("%s %s by %s: model picks %s (model %.2f g %.0f s; PS %.2f g %.0f s), "
                       "PS picks %s (model %.2f g %.0f s; PS %.2f g %.0f s)" %
                       (s, p, what, mine, a[2], a[3], a[0], a[1], theirs, b[2], b[3], b[0], b[1]))

for s, row in by_set.items():
    miss = {}
    for m in row["missing"]:
        ch, p = m.split(":", 1)
        miss.setdefault(ch, []).append(p)
    print("\n== set %s: totals over %d parts by PrusaSlicer, each choice against given over the parts it has "
          "figures on%s" % (s, row["n"], "".join("; no %s: %s" % (ch, " ".join(ps) if len(ps) <= 4 else "%d parts" % len(ps))
                                                 for ch, ps in miss.items())))
    print("  %-7s %5s %9s %8s %9s %8s  %s" % ("choice", "parts", "grams", "%", "hours", "%", "worse than given"))
    for ch in choices:
        n, g, t, g0, t0 = row[ch]
        if n:
            print("  %-7s %5d %9.2f %+8.1f %9.2f %+8.1f  %s" %
                  (ch, n, g, 100 * (g / g0 - 1) if g0 else 0, t / 3600, 100 * (t / t0 - 1) if t0 else 0,
                   " ".join(row.get("worse_" + ch, []))))
    print("  the oracle by grams keeps the part as given on %d of %d; our model mis-ranks %d by grams, %d by time" %
          (row["unchanged"], row["n"], row["mis_g"], row["mis_t"]))
if mis:
    print("\nmis-ranked (our model's pick against PrusaSlicer's, beyond its noise):")
    for m in mis:
        print("  " + m)
