/*
 * toolpath_gap.c - gap fill and thin walls: one line of matching width
 * along what the perimeter loops and the infill leave.
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include <math.h>

#include "../src/base/err.h"
#include "clip_shim.h"
#include "toolpath_int.h"

/* Move the pieces (outer and holes) of set narrower than t_mm (2 area /
   perimeter) to narrow; tmp is scratch. */
int
tp_split_narrow(struct paths *set, double t_mm, struct paths *narrow, struct paths *tmp)
{
    paths_reset(tmp);
    bool moved = false;
    for (uint32_t k = 0; k < set->n;) {
        uint32_t e = k + 1;
        while (e < set->n && paths_area_k(set, e) < 0)
            e++;
        double area = 0, per = 0;
        for (uint32_t i = k; i < e; i++) {
            area += paths_area_k(set, i);
            per += paths_length_k(set, i, true);
        }
        bool thin = per > 0 && 2 * area / per < t_mm;
        moved |= thin;
        for (uint32_t i = k; i < e; i++)
            if (!paths_add(thin ? narrow : tmp, set->pts + set->start[i], paths_len(set, i)))
                return SF_ENOMEM;
        k = e;
    }
    if (moved) {
        paths_reset(set);
        if (!paths_append(set, tmp))
            return SF_ENOMEM;
    }
    return SF_OK;
}

/* The vertex of q farthest from q[from]. */
static uint32_t
farthest(const struct ipt *q, uint32_t n, uint32_t from)
{
    uint32_t best = from;
    double bd = -1;
    for (uint32_t i = 0; i < n; i++) {
        double d = tp_d2(q[i], q[from]);
        if (d > bd)
            bd = d, best = i;
    }
    return best;
}

/*
 * Gap fill and thin walls: every piece of gap (a region no perimeter loop
 * or infill reaches, narrower than two lines) gets one line along its
 * middle instead of nothing.  The middle is found by shrinking the piece
 * to a sliver by nearly half its mean width (2 area / perimeter); a sliver
 * with a hole (a thin ring) prints its outer loop, an open one the side
 * between its two far ends.  The line's width is set so the piece's area
 * is laid down whole (length x spacing = area): a fixed width per piece,
 * the classic generator's answer to what PrusaSlicer's Arachne does with
 * widths varying along the line.
 */
int
tp_gap_fill(const struct paths *gap, double h, double nozzle, double sp, double overlap,
            double min_bead, struct layer_paths *out, struct paths *piece, struct paths *sliver,
            struct paths *line)
{
    int rc = SF_OK;
    for (uint32_t k = 0; k < gap->n && rc == SF_OK;) {
        /* one outer and its holes (Clipper's tree order) */
        uint32_t e = k + 1;
        while (e < gap->n && paths_area_k(gap, e) < 0)
            e++;
        paths_reset(piece);
        double area = 0, per = 0;
        uint32_t k_first = k;
        for (uint32_t i = k; i < e; i++) {
            if (!paths_add(piece, gap->pts + gap->start[i], paths_len(gap, i)))
                return SF_ENOMEM;
            area += paths_area_k(gap, i);
            per += paths_length_k(gap, i, true);
        }
        k = e;
        if (area < GAP_MIN_AREA * nozzle * nozzle || per <= 0)
            continue;
        double t = 2 * area / per;
        /* an infill piece at least min_bead_width wide is infill in
           PrusaSlicer too, grown infill_overlap into the loops around it
           (bonding): lay that band as well.  Narrower leftovers are what
           Arachne's beads absorb, without overlap. */
        double fill = overlap > 0 && t >= min_bead ? area + overlap * per : area;
        /* wider than 1.5 spacings: two lines, the loop a quarter width in */
        bool two = t > 1.5 * sp;
        /* a short piece (a corner's gap, a stub of wall) is one straight
           line between its far ends: no offsets for the many small ones */
        const struct ipt *o = piece->pts;
        uint32_t no = paths_len(piece, 0), fa = farthest(o, no, 0), fb = farthest(o, no, fa);
        double dia = sqrt(tp_d2(o[fa], o[fb])) / POLY_SCALE;
        if (!two && e == k_first + 1 && dia < 3) {
            struct ipt seg[2] = { o[fa], o[fb] };
            /* the line's ends sit half a width in from the piece's ends */
            double len = dia - t > 0.1 * dia ? dia - t : 0.1 * dia;
            double dx = (double)(o[fb].x - o[fa].x) / (dia * POLY_SCALE),
                   dy = (double)(o[fb].y - o[fa].y) / (dia * POLY_SCALE);
            double cut = (dia - len) / 2 * POLY_SCALE;
            seg[0].x += (int64_t)llround(dx * cut);
            seg[0].y += (int64_t)llround(dy * cut);
            seg[1].x -= (int64_t)llround(dx * cut);
            seg[1].y -= (int64_t)llround(dy * cut);
            paths_reset(line);
            if (!paths_add(line, seg, 2))
                return SF_ENOMEM;
            double wl = fill / len + h * (1 - M_PI / 4);
            rc = tp_add(out, line, ROLE_GAP_FILL, false, wl < 2.5 * nozzle ? wl : 2.5 * nozzle);
            continue;
        }
        paths_reset(sliver);
        for (double f = two ? 0.25 : 0.45; f > 0.1 && !sliver->n && rc == SF_OK; f -= 0.15)
            rc = clip_offset(piece, -f * t, CLIP_JOIN_MITER, sliver);
        if (rc < 0 || !sliver->n)
            continue;
        paths_reset(line);
        bool ring = two;
        for (uint32_t i = 0; i < sliver->n; i++)
            ring |= paths_area_k(sliver, i) < 0;
        double len = 0;
        for (uint32_t i = 0; i < sliver->n; i++) {
            const struct ipt *q = sliver->pts + sliver->start[i];
            uint32_t n = paths_len(sliver, i);
            if (paths_area_k(sliver, i) < 0 && !two)
                continue;
            if (ring) {
                if (!paths_add(line, q, n))
                    return SF_ENOMEM;
                len += paths_length_k(sliver, i, true);
                continue;
            }
            uint32_t a = farthest(q, n, 0), b = farthest(q, n, a);
            if (!paths_begin(line))
                return SF_ENOMEM;
            for (uint32_t j = a;; j = (j + 1) % n) {
                if (!paths_push(line, q[j]))
                    return SF_ENOMEM;
                if (j == b)
                    break;
            }
            len += paths_length_k(line, line->n - 1, false);
        }
        if (len < 1e-3)
            continue;
        double wl = fill / len + h * (1 - M_PI / 4);
        if (wl > 2.5 * nozzle)
            wl = 2.5 * nozzle;
        rc = tp_add(out, line, ROLE_GAP_FILL, ring, wl);
    }
    return rc;
}

/* A closed gap-fill line from out's path n0 on runs along a wall (the
   ring between the outer and the inner face's loops where no second loop
   fits, round a wall too thin for any, or the middle of a wall whose
   sparse strip is under a spacing wide): a wall line of its own width,
   which PrusaSlicer 2.5's Arachne prints as a perimeter bead. */
static void
rings_are_walls(struct layer_paths *out, uint32_t n0)
{
    for (uint32_t i = n0; i < out->p.n; i++)
        if (out->info[i].closed && out->info[i].role == ROLE_GAP_FILL)
            out->info[i].role = ROLE_PERIMETER;
}

/* The gap-fill lines from out's path n0 on fill a piece of skin: role r. */
static void
relabel(struct layer_paths *out, uint32_t n0, enum tp_role r)
{
    for (uint32_t i = n0; i < out->p.n; i++)
        if (out->info[i].role == ROLE_GAP_FILL)
            out->info[i].role = r;
}

int
tp_gap_fill_loops(double h, const struct slice_profile *p, double sp, struct paths *t,
                  struct layer_paths *out)
{
    int rc = SF_OK;
    if (t[T_GAP].n) {
        /* drop slivers under a quarter spacing wide (where the loops' bands
           meet at corners), then fill; pieces too small to fill go
           first (opening only shrinks them) */
        paths_reset(&t[T_TMP]);
        TP_TRY(tp_pieces_by_area(&t[T_GAP], GAP_MIN_AREA * p->nozzle_mm * p->nozzle_mm, 0, true,
                                 &t[T_TMP]));
        paths_move(&t[T_GAP], &t[T_TMP]);
        TP_TRY(clip_offset(&t[T_GAP], -sp / 8, CLIP_JOIN_MITER, &t[T_TMP]));
        TP_TRY(clip_offset(&t[T_TMP], sp / 8, CLIP_JOIN_MITER, &t[T_GAP]));
        uint32_t n0 = out->p.n;
        TP_TRY(tp_gap_fill(&t[T_GAP], h, p->nozzle_mm, sp, 0, 0, out, &t[T_TMP], &t[T_S],
                           &t[T_LINES]));
        rings_are_walls(out, n0);
    }
out:
    return rc;
}

int
tp_gap_fill_narrow(double h, const struct slice_profile *p, double sp, double ssp, struct paths *t,
                   struct layer_paths *out)
{
    int rc = SF_OK;
    /* solid and top pieces under 3.5 spacings wide: zig-zag links would
       lay more than their area there, so they get gap fill's lines
       instead; but they are the skin (PrusaSlicer 2.5 prints no gap fill
       there: its solid and top solid infill cover them), so the lines keep
       the skin's role and speed, the top's at top_solid_infill_speed */
    for (int top = 0; top < 2; top++) {
        paths_reset(&t[T_GAP]);
        TP_TRY(tp_split_narrow(&t[top ? T_TOP : T_SOLID], 3.5 * ssp, &t[T_GAP], &t[T_TMP]));
        uint32_t n0 = out->p.n;
        if (t[T_GAP].n)
            TP_TRY(tp_gap_fill(&t[T_GAP], h, p->nozzle_mm, ssp, p->infill_overlap * sp,
                               p->min_bead * p->nozzle_mm, out, &t[T_TMP], &t[T_S], &t[T_LINES]));
        relabel(out, n0, top ? ROLE_TOP : ROLE_SOLID);
    }
    /* sparse pieces stay sparse however narrow, as PrusaSlicer 2.5 fills
       the strip inside a 2-4 mm wall with anchored sparse lines (its
       PerimeterGenerator keeps an inner contour at least a perimeter
       spacing wide); narrower ones are what its Arachne beads widen
       over: gap fill laying their area, no overlap band */
    paths_reset(&t[T_GAP]);
    TP_TRY(tp_split_narrow(&t[T_SPARSE], sp, &t[T_GAP], &t[T_TMP]));
    uint32_t n0 = out->p.n;
    if (t[T_GAP].n)
        TP_TRY(tp_gap_fill(&t[T_GAP], h, p->nozzle_mm, ssp, 0, 0, out, &t[T_TMP], &t[T_S],
                           &t[T_LINES]));
    rings_are_walls(out, n0);
out:
    return rc;
}
