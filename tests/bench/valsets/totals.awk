# totals.awk - bench_supgrams.sh's totals over its rows, one a line:
#   set mesh variant PS_g PS_s CE_g CE_s ours_g MNDR% ANDR% md5
# ("-" or "fail" where a figure is missing).  -v set=NAME: that set's totals
# per variant against the part as given; -v side=1: every set's % changes
# side by side.  -v vars="given orient ..." gives the variants' order.
# A variant's sum covers the parts where it and the part as given both have
# the figure (so a missing peer row leaves the part out of that column only).
# worse: either peer's support rose beyond 2 % + 0.05 g (slicer noise);
# slower: PrusaSlicer's estimate rose over 2 %; same: the same STL, or
# grams within 0.5 % + 0.02 g of the part as given in every peer with both
# figures (the optimizer handed the part back, perhaps rewritten; a run of
# PrusaSlicer alone counted only identical files), not counting the
# parts that need no support as given (none: at most 0.05 g, slicer noise,
# in every peer with a figure), which are rightly handed back: they are
# counted apart, and "same" is what the one-in-ten rule of issue 36 reads.
function num(x) { return x ~ /^-?[0-9.]+$/ }
function near(a, b) { return num(a) && num(b) && (a - b <= 0.005 * b + 0.02) && (b - a <= 0.005 * b + 0.02) }
# a peer without both figures says nothing; at least one must say near
function near2(a, b, c, d) { return (near(a, b) || !num(a) || !num(b)) && (near(c, d) || !num(c) || !num(d)) && (near(a, b) || near(c, d)) }
function nosup(g, c) { return (num(g) || num(c)) && (!num(g) || g <= 0.05) && (!num(c) || c <= 0.05) }
function pct(a, b) { return b > 0 ? sprintf("%+.1f%%", 100 * (a - b) / b) : "-" }
{
  sets[$1] = 1; key = $1 SUBSEP $2
  if ($3 == "given") { gps[key] = $4; gpt[key] = $5; gce[key] = $6; gours[key] = $8; gmd5[key] = $11; parts[$1]++ }
  n++; s[n] = $1; m[n] = $2; v[n] = $3; ps[n] = $4; pt[n] = $5; ce[n] = $6; ours[n] = $8
  mndr[n] = $9; andr[n] = $10; md5[n] = $11
}
END {
  nv = split(vars, order, " ")
  for (i = 1; i <= n; i++) {
    key = s[i] SUBSEP m[i]
    if (!(key in gmd5)) continue
    t = s[i] SUBSEP v[i]; cnt[t]++
    if (num(ps[i]) && num(gps[key])) { a_ps[t] += ps[i]; b_ps[t] += gps[key] }
    if (num(pt[i]) && num(gpt[key])) { a_pt[t] += pt[i]; b_pt[t] += gpt[key]; if (pt[i] > 1.02 * gpt[key]) slow[t]++ }
    if (num(ce[i]) && num(gce[key])) { a_ce[t] += ce[i]; b_ce[t] += gce[key] }
    if (num(ours[i]) && num(gours[key])) { a_ou[t] += ours[i]; b_ou[t] += gours[key] }
    if ((num(ps[i]) && num(gps[key]) && ps[i] > 1.02 * gps[key] + 0.05) ||
        (num(ce[i]) && num(gce[key]) && ce[i] > 1.02 * gce[key] + 0.05)) worse[t]++
    if (v[i] != "given" && nosup(gps[key], gce[key])) none[t]++
    else if (v[i] != "given" && (md5[i] == gmd5[key] || near2(ps[i], gps[key], ce[i], gce[key]))) same[t]++
    if (num(mndr[i]) && mndr[i] > mx_m[t]) mx_m[t] = mndr[i]
    if (num(andr[i]) && andr[i] > mx_a[t]) mx_a[t] = andr[i]
  }
  if (!side) {
    printf "-- totals, set %s (%d parts; %% against the part as given; worse/slower/same/none: parts; none: no support needed as given)\n", set, parts[set]
    printf "%-8s | %8s %7s | %7s %7s | %8s %7s | %8s %7s | %5s %6s %4s %4s | %6s %6s\n", "variant", "PS_g", "%", "PS_h",
      "%", "CE_g", "%", "ours_g", "%", "worse", "slower", "same", "none", "MNDR%", "ANDR%"
    for (j = 1; j <= nv; j++) {
      t = set SUBSEP order[j]
      if (!cnt[t]) continue
      printf "%-8s | %8.2f %7s | %7.2f %7s | %8.2f %7s | %8.2f %7s | %5d %6d %4s %4s | %6s %6s\n", order[j],
        a_ps[t], pct(a_ps[t], b_ps[t]), a_pt[t] / 3600, pct(a_pt[t], b_pt[t]), a_ce[t], pct(a_ce[t], b_ce[t]),
        a_ou[t], pct(a_ou[t], b_ou[t]), worse[t], slow[t], order[j] == "given" ? "-" : same[t] + 0,
        order[j] == "given" ? "-" : none[t] + 0,
        t in mx_m ? sprintf("%.2f", mx_m[t]) : "-", t in mx_a ? sprintf("%.2f", mx_a[t]) : "-"
    }
    exit
  }
  ns = 0
  for (x in sets) { names[++ns] = x; for (k = ns; k > 1 && names[k - 1] > names[k]; k--) { y = names[k]; names[k] = names[k - 1]; names[k - 1] = y } }
  printf "-- side by side: %% change against the part as given (PrusaSlicer support g / CuraEngine support g / PrusaSlicer time), parts worse/same/none\n"
  printf "%-8s", "variant"
  for (k = 1; k <= ns; k++) printf " | %-34s", names[k] " (" parts[names[k]] ")"
  printf "\n"
  for (j = 1; j <= nv; j++) {
    if (order[j] == "given") continue
    printf "%-8s", order[j]
    for (k = 1; k <= ns; k++) {
      t = names[k] SUBSEP order[j]
      if (!cnt[t]) { printf " | %-34s", "-"; continue }
      printf " | %-34s", sprintf("%s / %s / %s  %d/%d/%d", pct(a_ps[t], b_ps[t]), pct(a_ce[t], b_ce[t]),
        pct(a_pt[t], b_pt[t]), worse[t], same[t], none[t])
    }
    printf "\n"
  }
}
