/*
 * toolpath.h - what the nozzle draws on each layer: perimeters, solid and
 * sparse infill, support, each path tagged with its role and line width.
 *
 * Per layer, from the cross-sections (layers.h) and the support regions
 * (support.h): perimeter loops by inward offsets of the region (outermost
 * is the external perimeter); the rest is the infill area, split into
 * top solid (not covered by the layer above), other solid (the top and
 * bottom surfaces of the layers within reach, grown skin_margin and
 * projected onto this one, as PrusaSlicer's discover_horizontal_shells;
 * or, with vertical_shells, wherever the areas inside the perimeters of
 * the top_layers above and bottom_layers below do not all cover it, like
 * its "ensure vertical shell thickness"; plus the internal pieces, away
 * from the layer's own top and bottom surfaces, smaller than
 * solid_below_mm2) and sparse infill (grid or rectilinear lines at a
 * spacing set by the density, joined along the boundary).  Paths come in
 * print order of roles: support, interface, perimeters (inner first,
 * external last), solid, top, sparse.
 *
 * Line geometry follows PrusaSlicer's flow model: a line of width w on
 * layer h has cross-section h (w - h (1 - pi/4)), which is also the
 * spacing between neighbouring lines, so length x spacing x h is the
 * volume laid down.
 *
 * Thread: toolpath_layer on distinct outputs is reentrant.
 */
#ifndef SF_SLICER_TOOLPATH_H
#define SF_SLICER_TOOLPATH_H

#include <stdint.h>

#include "layers.h"
#include "poly.h"
#include "profile.h"

enum tp_role {
    ROLE_SUPPORT,
    ROLE_INTERFACE,
    ROLE_PERIMETER,
    ROLE_EXT_PERIMETER,
    ROLE_SOLID,
    ROLE_TOP,
    ROLE_INFILL,
    ROLE_BRIDGE,   /* solid over air: round lines of nozzle width, bridge speed */
    ROLE_SKIRT,    /* skirt and brim */
    ROLE_GAP_FILL, /* one line along a gap or thin wall, its width set by the gap's area */
    ROLE_OVERHANG, /* the part of a perimeter loop over air (layer_paths.ovh): bridge flow */
    ROLE_N
};

/* PrusaSlicer's ;TYPE: name of a role ("External perimeter"). */
const char *tp_role_name(enum tp_role r);
/* True for the two support roles. */
static inline int
tp_role_is_support(int r)
{
    return r == ROLE_SUPPORT || r == ROLE_INTERFACE;
}

struct tp_info {
    uint8_t role;   /* enum tp_role */
    uint8_t closed; /* a loop: the writer returns to its first point */
    float width_mm;
};

/*
 * The paths of one layer; info[k] describes path k of p.  ovh, when not
 * NULL, has one flag per point of p: 1 when the segment from that point
 * to the next one of its path (a loop's last point: to its first) runs
 * over air, a nozzle width out from the layer below (PrusaSlicer's
 * overhang perimeters); only perimeter loops have such segments.
 */
struct layer_paths {
    struct paths p;
    struct tp_info *info;
    uint32_t cap_info;
    uint8_t *ovh;
    size_t cap_ovh;
};

void layer_paths_init(struct layer_paths *lp);
void layer_paths_release(struct layer_paths *lp);

/* Spacing of lines of width w on layer height h (the flow model). */
double tp_spacing(double w_mm, double h_mm);

/* Support regions of one layer: the body and its dense interface. */
struct support_layer {
    struct paths body, iface;
};

/*
 * Compute s->l[k].inner, the area inside layer k's perimeters.  Every
 * layer's inner must exist before toolpath_layer runs on any layer.
 */
int toolpath_areas(struct layer_stack *s, uint32_t k, const struct slice_profile *p);

/*
 * The infill area of layer k (its inner area) split into solid, top solid
 * and sparse regions (after toolpath_areas on all layers; bridges are
 * split off the solid later, by toolpath_layer).  The outputs are reset
 * first.  SF_ENOMEM / SF_EBUG.
 */
int toolpath_regions(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                     struct paths *solid, struct paths *top, struct paths *sparse);

/*
 * toolpath_regions of layer k kept in s->l[k] (solid, top, sparse,
 * has_regions), after toolpath_areas on all layers: toolpath_layer uses
 * them, and the layer above lays internal bridges over the sparse part.
 * Optional: toolpath_layer computes what is not kept.  SF_ENOMEM / SF_EBUG.
 */
int toolpath_store_regions(struct layer_stack *s, uint32_t k, const struct slice_profile *p);
/*
 * Build the paths of layer k of s (after toolpath_areas on all layers).  sup (may be NULL) is that
 * layer's support.  SF_ENOMEM / SF_EBUG (Clipper).
 */
int toolpath_layer(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                   const struct support_layer *sup, struct layer_paths *out);

/*
 * The brim width layer 0 gets: brim_width, or with brim_auto and no
 * brim_width, brim_auto_width when the part stands tall on a small
 * footprint: height_mm > brim_auto_ratio x the hydraulic diameter of the
 * first layer (4 area / perimeter: the side of a square, the diameter of
 * a disc, twice the width of a long strip).  0: no brim.
 */
double tp_brim_width(const struct layer_stack *s, const struct slice_profile *p, double height_mm);

/*
 * Put the skirt (layers below skirt_height) and the brim (layer 0, brim_mm
 * wide, outside the part's outer contours only) in front of layer k's
 * paths.  The brim keeps a line width clear of that layer's support
 * (sup0: layer 0's support, may be NULL); the skirt loops run
 * skirt_distance outside the convex hull of layer 0's part, support and
 * brim, so they go around everything.  SF_ENOMEM / SF_EBUG.
 */
int toolpath_skirt_brim(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                        const struct support_layer *sup0, double brim_mm, struct layer_paths *lp);

/*
 * Parallel lines at angle_deg, spacing_mm apart, one of them through
 * (ox_mm, oy_mm) (the part's centre, so its layers line up; 0, 0: the bed
 * origin), cut to region (nonzero rule), appended to out as open paths.
 */
int tp_fill_lines(const struct paths *region, double angle_deg, double spacing_mm, double ox_mm,
                  double oy_mm, struct paths *out);

/*
 * Join lines end to end into zig-zag polylines: from each line's end to
 * the nearest free line end within link_max_mm, if the link stays inside
 * region grown by grow_mm (sampled at 3 points).  Replaces lines.
 */
int tp_link(struct paths *lines, const struct paths *region, double link_max_mm, double grow_mm);

/*
 * Join and anchor open lines clipped to region, as PrusaSlicer's
 * connect_infill does: the arcs of boundary between neighbouring line ends,
 * shortest first, each join two lines not yet joined (no loops) along the
 * whole arc when it is shorter than max_mm; an end left over gets a stub
 * along the boundary of up to len_mm, toward the side with more boundary
 * free, stopping half_w_mm short of the next line end or stub.  Replaces
 * lines.  SF_ENOMEM.
 */
int tp_anchor(struct paths *lines, const struct paths *region, double len_mm, double max_mm,
              double half_w_mm);

#endif
