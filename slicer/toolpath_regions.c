/*
 * toolpath_regions.c - a layer's inner area and skins (toolpath_areas),
 * and its infill area split into solid, top solid and sparse regions
 * (toolpath_regions; see toolpath.h).
 *
 * Reads the neighbouring layers' areas and skins, so every layer's
 * toolpath_areas runs before any layer's toolpath_regions.
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include "../src/base/err.h"
#include "clip_shim.h"
#include "toolpath_int.h"

/* out = intersection of the inner areas of layers [a, b); empty if the
   range leaves the stack (a surface is within reach). */
static int
intersect_range(const struct layer_stack *s, long a, long b, struct paths *out)
{
    paths_reset(out);
    if (a < 0 || b > (long)s->n)
        return SF_OK;
    struct paths tmp;
    paths_init(&tmp);
    if (!paths_append(out, &s->l[a].inner)) {
        paths_release(&tmp);
        return SF_ENOMEM;
    }
    int rc = SF_OK;
    for (long j = a + 1; j < b && rc == SF_OK && out->n; j++) {
        rc = clip_bool(CLIP_INTERSECTION, out, &s->l[j].inner, CLIP_NONZERO, &tmp);
        paths_move(out, &tmp);
    }
    paths_release(&tmp);
    return rc;
}

/*
 * The skin of one surface a (the cross-section open to the air on one
 * side; a is used up): without slivers under a tenth of a line wide, as
 * PrusaSlicer 2.5 finds top and bottom surfaces (detect_surfaces_type:
 * opening by the external perimeter width / 10), then kept where it
 * reaches fill (the inner area grown infill_overlap into the loops:
 * PrusaSlicer's fill_expolygons, to which slices_to_fill_surfaces_clipped
 * trims its surfaces), grown skin_margin into the inner area.  The skin is that
 * grown part and the surface itself, perimeter zone included: projected
 * onto the layers within reach, a sloping surface's band lands inside
 * their inner areas (PrusaSlicer's discover_horizontal_shells projects
 * the slices' surfaces so).  b, c: scratch; reach (may be NULL) gets the
 * surface's part in the inner area appended.
 */
static int
skin_of(struct paths *a, const struct paths *inner, const struct paths *fill,
        const struct slice_profile *p, struct paths *b, struct paths *c, struct paths *out,
        struct paths *reach)
{
    paths_reset(out);
    paths_reset(c);
    if (!a->n)
        return SF_OK;
    double open = p->width_mm / 10;
    int rc = clip_offset(a, -open, CLIP_JOIN_MITER, b);
    if (rc < 0 || !b->n)
        return rc;
    if ((rc = clip_offset(b, open, CLIP_JOIN_MITER, a)) < 0)
        return rc;
    if ((rc = clip_bool(CLIP_INTERSECTION, a, fill, CLIP_NONZERO, b)) < 0)
        return rc;
    if (reach && !paths_append(reach, b))
        return SF_ENOMEM;
    if (b->n && (rc = clip_offset(b, p->skin_margin_mm, CLIP_JOIN_SQUARE, c)) < 0)
        return rc;
    paths_reset(b);
    if (c->n && (rc = clip_bool(CLIP_INTERSECTION, c, inner, CLIP_NONZERO, b)) < 0)
        return rc;
    if (!paths_append(b, a))
        return SF_ENOMEM;
    return b->n ? clip_bool(CLIP_UNION, b, NULL, CLIP_NONZERO, out) : SF_OK;
}

/* Append to out the pieces (an outer and its holes) of set whose area,
   grown grow_mm all round, is at most lim_mm2 (above: at least).  The
   grown area is the area plus grow_mm x the perimeter (Steiner's formula,
   without its grow^2 term). */
int
tp_pieces_by_area(const struct paths *set, double lim_mm2, double grow_mm, bool above,
                  struct paths *out)
{
    for (uint32_t a = 0, b; a < set->n; a = b) {
        double area = paths_area_k(set, a);
        if (grow_mm > 0)
            area += grow_mm * paths_length_k(set, a, true);
        for (b = a + 1; b < set->n && paths_area_k(set, b) < 0; b++)
            area += paths_area_k(set, b) + grow_mm * paths_length_k(set, b, true);
        if (above ? area < lim_mm2 : area > lim_mm2)
            continue;
        for (uint32_t j = a; j < b; j++)
            if (!paths_add(out, set->pts + set->start[j], paths_len(set, j)))
                return SF_ENOMEM;
    }
    return SF_OK;
}

int
toolpath_areas(struct layer_stack *s, uint32_t k, const struct slice_profile *p)
{
    struct layer *L = &s->l[k];
    double sp = tp_spacing(p->width_mm, L->h_mm);
    paths_reset(&L->inner);
    paths_reset(&L->skin);
    paths_reset(&L->skin_bottom);
    paths_reset(&L->small);
    paths_reset(&L->top_in);
    int rc;
    if (p->perimeters > 0) {
        rc = tp_extra_perimeters(s, k, p);
        if (rc == SF_OK)
            rc = tp_inner(L, p, sp, &L->inner);
    } else
        rc = paths_append(&L->inner, &L->region) ? SF_OK : SF_ENOMEM;
    if (rc < 0 || !L->inner.n)
        return rc;
    /* the seeds of the skins: the cross-section open to the air above
       (top) and below (bottom), each its own skin, since a top surface
       thickens the layers under it and a bottom surface those over it,
       never the other way (PrusaSlicer's discover_horizontal_shells; one
       skin for both put solid under every overhang and over every top) */
    struct paths a, b, c, seeds, fill;
    paths_init(&fill);
    if (p->infill_overlap > 0)
        rc = clip_offset(&L->inner, p->infill_overlap * sp, CLIP_JOIN_MITER, &fill);
    else if (!paths_append(&fill, &L->inner))
        rc = SF_ENOMEM;
    paths_init(&a);
    paths_init(&b);
    paths_init(&c);
    paths_init(&seeds);
    for (int side = 0; side < 2 && rc == SF_OK; side++) {
        struct paths *out = side ? &L->skin_bottom : &L->skin;
        long nb = side ? (long)k - 1 : (long)k + 1;
        if (nb >= 0 && nb < (long)s->n)
            rc = clip_bool(CLIP_DIFFERENCE, &L->region, &s->l[nb].region, CLIP_NONZERO, &a);
        else
            rc = paths_append(&a, &L->region) ? SF_OK : SF_ENOMEM;
        if (rc == SF_OK)
            rc = skin_of(&a, &L->inner, &fill, p, &b, &c, out, side ? &seeds : &L->top_in);
        paths_reset(&a);
    }
    if (rc == SF_OK && !paths_append(&seeds, &L->top_in))
        rc = SF_ENOMEM;
    if (rc == SF_OK && p->solid_below_mm2 > 0 && p->infill_density > 0) {
        /* the inner area away from this layer's own top and bottom
           surfaces, piece by piece: pieces no larger than
           solid_infill_below_area print solid (PrusaSlicer's
           prepare_fill_surfaces, which sees the internal surfaces before
           the skins of other layers are projected onto them, so a big
           island that the skins cut into small pieces stays sparse; its
           surfaces reach infill_overlap into the loops, so do ours here) */
        const struct paths *in = &L->inner; /* seeds: the surfaces' parts in it */
        if (seeds.n) {
            rc = clip_bool(CLIP_DIFFERENCE, &L->inner, &seeds, CLIP_NONZERO, &b);
            in = &b;
        }
        if (rc == SF_OK)
            rc =
                tp_pieces_by_area(in, p->solid_below_mm2, p->infill_overlap * sp, false, &L->small);
    }
    paths_release(&a);
    paths_release(&b);
    paths_release(&c);
    paths_release(&seeds);
    paths_release(&fill);
    return rc;
}

/* Vertical shells (ensure_vertical_shells): t[T_SOLID] = t[T_AREA]
   wherever the inner areas of the top_layers above and the bottom_layers
   below do not all cover it; t[T_KEEP] = what they all cover. */
static int
vertical_shells(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                struct paths *t)
{
    int rc;
    TP_TRY(intersect_range(s, (long)k + 1, (long)k + 1 + p->top_layers, &t[T_TOPI]));
    if (p->top_layers == 0 && !paths_append(&t[T_TOPI], &t[T_AREA]))
        TP_TRY(SF_ENOMEM);
    TP_TRY(intersect_range(s, (long)k - p->bottom_layers, (long)k, &t[T_BOTI]));
    if (p->bottom_layers == 0 && !paths_append(&t[T_BOTI], &t[T_AREA]))
        TP_TRY(SF_ENOMEM);
    TP_TRY(clip_bool(CLIP_INTERSECTION, &t[T_TOPI], &t[T_BOTI], CLIP_NONZERO, &t[T_KEEP]));
    TP_TRY(clip_bool(CLIP_DIFFERENCE, &t[T_AREA], &t[T_KEEP], CLIP_NONZERO, &t[T_SOLID]));
out:
    return rc;
}

/* t[T_SOLID] gets the skins of the layers within reach projected onto
   t[T_AREA] (added to what it holds), bands of it narrower than 3 solid
   lines widened (without vertical shells: t[T_KEEP] is then emptied). */
static int
projected_skins(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                struct paths *t)
{
    const struct layer *L = &s->l[k];
    int rc = SF_OK;
    /* the top and bottom surfaces of the layers within reach (top_layers
       - 1 above, bottom_layers - 1 below, and this one), grown
       skin_margin into the infill: PrusaSlicer 2.5 grows them 3 mm
       (EXTERNAL_INFILL_MARGIN) and projects them so
       (discover_horizontal_shells) */
    paths_reset(&t[T_LINES]);
    for (long j = k; j < (long)k + p->top_layers && j < (long)s->n; j++)
        if (!paths_append(&t[T_LINES], &s->l[j].skin))
            TP_TRY(SF_ENOMEM);
    for (long j = k; j > (long)k - p->bottom_layers && j >= 0; j--)
        if (!paths_append(&t[T_LINES], &s->l[j].skin_bottom))
            TP_TRY(SF_ENOMEM);
    /* PrusaSlicer's infill areas reach infill_overlap into the loops
       (its fill_expolygons): a skin projected from a slope can end
       just inside them, short of the inner area, and its sliver there
       grows below into a band of solid along the slope */
    bool grown = !p->vertical_shells && p->infill_overlap > 0 && t[T_LINES].n;
    if (grown)
        TP_TRY(clip_offset(&t[T_AREA], p->infill_overlap * tp_spacing(p->width_mm, L->h_mm),
                           CLIP_JOIN_MITER, &t[T_BELOW]));
    if (t[T_LINES].n) {
        /* one pass: under the nonzero rule the overlapping skins are
           their union, clipped to the area at once (a separate union
           of the stacked skins first cost 41 % of knot1's
           instructions, most of it joining their common edges) */
        if (!paths_append(&t[T_LINES], &t[T_SOLID]))
            TP_TRY(SF_ENOMEM);
        TP_TRY(clip_bool(CLIP_INTERSECTION, &t[T_LINES], grown ? &t[T_BELOW] : &t[T_AREA],
                         CLIP_NONZERO, &t[T_SOLID]));
    }
    if (!p->vertical_shells && t[T_SOLID].n) {
        /* bands narrower than 3 solid lines grow 3 lines wider, so
           the solid can be filled and holds (PrusaSlicer's "too
           narrow" regularization in discover_horizontal_shells) */
        double mg = 3 * p->solid_width_mm;
        TP_TRY(clip_offset(&t[T_SOLID], -mg, CLIP_JOIN_MITER, &t[T_TMP]));
        /* grown back a grid unit more (PrusaSlicer's ClipperSafetyOffset,
           the same 10 nm): the offsets' rounding leaves hairlines along
           slanted edges, and a hairline is not a band too narrow */
        TP_TRY(clip_offset(&t[T_TMP], mg + 1 / POLY_SCALE, CLIP_JOIN_MITER, &t[T_KEEP]));
        TP_TRY(clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &t[T_KEEP], CLIP_NONZERO, &t[T_TMP]));
        if (t[T_TMP].n) {
            TP_TRY(clip_offset(&t[T_TMP], mg, CLIP_JOIN_MITER, &t[T_LINES]));
            if (!paths_append(&t[T_LINES], &t[T_SOLID]))
                TP_TRY(SF_ENOMEM);
            TP_TRY(clip_bool(CLIP_UNION, &t[T_LINES], NULL, CLIP_NONZERO, &t[T_TMP]));
            TP_TRY(clip_bool(CLIP_INTERSECTION, &t[T_TMP], &t[T_AREA], CLIP_NONZERO, &t[T_SOLID]));
        } else if (grown) {
            TP_TRY(clip_bool(CLIP_INTERSECTION, &t[T_SOLID], &t[T_AREA], CLIP_NONZERO, &t[T_TMP]));
            paths_move(&t[T_SOLID], &t[T_TMP]);
        }
        paths_reset(&t[T_KEEP]);
    }
out:
    return rc;
}

/*
 * Without vertical shells, t[T_SOLID] = this layer's own skins and each
 * other layer's within reach projected onto t[T_AREA], as PrusaSlicer
 * 2.5's discover_horizontal_shells projects them: one layer's surfaces at
 * a time, onto the infill area (reaching infill_overlap into the loops)
 * less this layer's own surfaces, and a projection with bands narrower
 * than 3 solid lines grows 3 lines there.  On a slope every layer's
 * projection is such a band beyond the ones before: PrusaSlicer's skin
 * reaches 3 lines past the farthest.  Regularizing the union instead (a
 * wide band on a slope) left ours short by those 3 lines.
 */
static int
projected_skins_each(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                     struct paths *t)
{
    const struct layer *L = &s->l[k];
    int rc = SF_OK;
    struct paths *own = &t[T_LINES], *internal = &t[T_TOPI], *piece = &t[T_S];
    paths_reset(own);
    if (!paths_append(own, &L->skin) || !paths_append(own, &L->skin_bottom))
        TP_TRY(SF_ENOMEM);
    if (p->infill_overlap > 0)
        TP_TRY(clip_offset(&t[T_AREA], p->infill_overlap * tp_spacing(p->width_mm, L->h_mm),
                           CLIP_JOIN_MITER, &t[T_BELOW]));
    else if (!paths_append(&t[T_BELOW], &t[T_AREA]))
        TP_TRY(SF_ENOMEM);
    TP_TRY(clip_bool(CLIP_DIFFERENCE, &t[T_BELOW], own, CLIP_NONZERO, internal));
    double mg = 3 * p->solid_width_mm;
    for (int side = 0; side < 2 && internal->n; side++) {
        long n = side ? p->bottom_layers : p->top_layers;
        for (long d = 1; d < n; d++) {
            long j = side ? (long)k - d : (long)k + d;
            if (j < 0 || j >= (long)s->n)
                break;
            const struct paths *sk = side ? &s->l[j].skin_bottom : &s->l[j].skin;
            if (!sk->n)
                continue;
            TP_TRY(clip_bool(CLIP_INTERSECTION, sk, internal, CLIP_NONZERO, piece));
            if (!piece->n)
                continue;
            /* its bands too narrow: what an opening by 3 lines (regrown
               ClipperSafetyOffset more) leaves out */
            TP_TRY(clip_offset(piece, -mg, CLIP_JOIN_MITER, &t[T_TMP]));
            struct paths *narrow = piece; /* all of it, mostly: a band along a slope */
            if (t[T_TMP].n) {
                TP_TRY(clip_offset(&t[T_TMP], mg + 1 / POLY_SCALE, CLIP_JOIN_MITER, &t[T_KEEP]));
                TP_TRY(clip_bool(CLIP_DIFFERENCE, piece, &t[T_KEEP], CLIP_NONZERO, &t[T_TMP]));
                narrow = &t[T_TMP];
            }
            /* grown, they are kept in the internal area: the final clip
               to the area does it, since own is all the rest there */
            if (narrow->n) {
                TP_TRY(clip_offset(narrow, mg, CLIP_JOIN_MITER, &t[T_C]));
                if (!paths_append(own, &t[T_C]))
                    TP_TRY(SF_ENOMEM);
            }
            if (!paths_append(own, piece))
                TP_TRY(SF_ENOMEM);
        }
    }
    /* one pass: under the nonzero rule the pieces are their union */
    paths_reset(&t[T_SOLID]);
    if (own->n)
        TP_TRY(clip_bool(CLIP_INTERSECTION, own, &t[T_AREA], CLIP_NONZERO, &t[T_SOLID]));
    paths_reset(&t[T_KEEP]);
out:
    return rc;
}

int
toolpath_regions(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                 struct paths *solid, struct paths *top, struct paths *sparse)
{
    const struct layer *L = &s->l[k];
    double ssp = tp_spacing(p->solid_width_mm, L->h_mm);
    struct paths t[T_N];
    tp_scratch_init(t);
    paths_reset(solid);
    paths_reset(top);
    paths_reset(sparse);
    int rc = SF_OK;
    if (!paths_append(&t[T_AREA], &L->inner))
        TP_TRY(SF_ENOMEM);
    if (!t[T_AREA].n)
        goto out;
    /* solid wherever the inner areas of the top_layers above and the
       bottom_layers below do not all cover it: keeps the shell thick
       on slopes (PrusaSlicer's ensure_vertical_shell_thickness, off by
       default and in the peers' runs) */
    if (p->vertical_shells)
        TP_TRY(vertical_shells(s, k, p, t));
    if (p->vertical_shells)
        TP_TRY(projected_skins(s, k, p, t));
    else
        TP_TRY(projected_skins_each(s, k, p, t));
    if (t[T_SOLID].n && t[T_KEEP].n) {
        /* solid narrower than a line is a sliver along a slope, not a
           skin: drop it and grow the rest a little, as PrusaSlicer 2.5
           regularizes its vertical shells: offset2(-0.5 s, +0.8 s) with
           s = 1.05 x the solid line spacing (min_perimeter_infill_spacing
           in PrintObject::discover_vertical_shells) */
        double ms = 1.05 * ssp;
        TP_TRY(clip_offset(&t[T_SOLID], -0.5 * ms, CLIP_JOIN_SQUARE, &t[T_TMP]));
        TP_TRY(clip_offset(&t[T_TMP], 0.8 * ms, CLIP_JOIN_SQUARE, &t[T_LINES]));
        TP_TRY(clip_bool(CLIP_INTERSECTION, &t[T_LINES], &t[T_AREA], CLIP_NONZERO, &t[T_SOLID]));
    }
    if (L->small.n && p->solid_below_mm2 > 0 && p->infill_density > 0) {
        /* internal pieces too small for the grid to hold anything print
           solid (solid_infill_below_area, 70 mm2: thin limbs, ears and
           tails; toolpath_areas found them) */
        paths_reset(&t[T_LINES]);
        if (!paths_append(&t[T_LINES], &L->small) || !paths_append(&t[T_LINES], &t[T_SOLID]))
            TP_TRY(SF_ENOMEM);
        TP_TRY(clip_bool(CLIP_UNION, &t[T_LINES], NULL, CLIP_NONZERO, &t[T_SOLID]));
    }
    TP_TRY(clip_bool(CLIP_DIFFERENCE, &t[T_AREA], &t[T_SOLID], CLIP_NONZERO, &t[T_SPARSE]));
    if (p->top_layers > 0) {
        /* the solid on this layer's top surface (opened, as
           PrusaSlicer's detect_surfaces_type finds stTop) is top solid;
           most layers of a smooth part have none inside the loops */
        if (k + 1 < s->n) {
            if (L->top_in.n && t[T_SOLID].n) {
                TP_TRY(
                    clip_bool(CLIP_INTERSECTION, &t[T_SOLID], &L->top_in, CLIP_NONZERO, &t[T_TOP]));
                TP_TRY(
                    clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &L->top_in, CLIP_NONZERO, &t[T_TMP]));
                paths_move(&t[T_SOLID], &t[T_TMP]);
            }
        } else {
            paths_move(&t[T_TOP], &t[T_SOLID]);
        }
    }
    paths_move(solid, &t[T_SOLID]);
    paths_move(top, &t[T_TOP]);
    paths_move(sparse, &t[T_SPARSE]);
out:
    tp_scratch_release(t);
    return rc;
}

int
toolpath_store_regions(struct layer_stack *s, uint32_t k, const struct slice_profile *p)
{
    struct layer *L = &s->l[k];
    int rc = toolpath_regions(s, k, p, &L->solid, &L->top, &L->sparse);
    L->has_regions = rc == SF_OK;
    return rc;
}

/* The regions of layer k: kept ones copied, else computed. */
int
tp_regions_of(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
              struct paths *solid, struct paths *top, struct paths *sparse)
{
    const struct layer *L = &s->l[k];
    if (!L->has_regions)
        return toolpath_regions(s, k, p, solid, top, sparse);
    paths_reset(solid);
    paths_reset(top);
    paths_reset(sparse);
    return paths_append(solid, &L->solid) && paths_append(top, &L->top) &&
                   paths_append(sparse, &L->sparse)
               ? SF_OK
               : SF_ENOMEM;
}
