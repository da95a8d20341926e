// bracket.scad - an L bracket: two legs (a along x, b up z) t thick and w
// wide, ng triangular gussets in the inner corner, two screw holes in each
// leg (beside a single gusset: two rows).  Modelled base leg on the bed;
// rot = [90, 0, 0] is the bracket on its side (the holes then run
// horizontally, the gussets bridge the corner).
include <common.scad>
a = 50; b = 40; t = 4; w = 30; ng = 2; g = 0.6; hole = 4.2;
rot = [0, 0, 0];
$fn = 32;

module part() {
    difference() {
        union() {
            cube([a, w, t]);
            cube([t, w, b]);
            for (i = [0 : ng - 1])
                translate([0, ng == 1 ? w / 2 - t / 2 : i * (w - t) / (ng - 1), 0])
                    rotate([90, 0, 0]) translate([0, 0, -t]) linear_extrude(t)
                        polygon([[t - 0.01, t - 0.01], [t + g * (a - t), t - 0.01], [t - 0.01, t + g * (b - t)]]);
        }
        // holes clear of the gussets: beside a middle one, between two at the edges
        ys = ng == 1 ? [w / 4, 3 * w / 4] : [w / 2];
        for (y = ys, f = [0.4, 0.75]) {
            translate([t + (a - t) * f, y, 0]) screw_hole(hole, t);
            translate([0, y, t + (b - t) * f]) hbore(hole, 3 * t);
        }
    }
}
rotate(rot) part();
