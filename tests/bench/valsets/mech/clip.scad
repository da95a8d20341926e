// clip.scad - a tube clip: a C ring for a tube of diameter D (ring t thick,
// w wide, open by `open` degrees) on a mounting tab with a screw hole.
// Modelled with the ring's axis horizontal (y), tab on the bed;
// rot = [0, 90, 0] is the clip as mounted on a wall (tab upright, the ring
// sticking out of it).
include <common.scad>
D = 20; t = 2.4; w = 12; open = 100; tab = 10; tab_t = 3; hole = 3.4;
rot = [0, 0, 0];
$fn = 64;

module ring2d() {
    difference() {
        circle(d = D + 2 * t);
        circle(d = D);
        rotate(90 - open / 2) polygon([[0, 0], [D * 2, 0], [D * 2 * cos(open), D * 2 * sin(open)]]);
    }
}
module part() {
    difference() {
        union() {
            translate([0, 0, D / 2 + t]) rotate([90, 0, 0]) linear_extrude(w, center = true) ring2d();
            translate([-(D / 2 + t + tab), -w / 2, 0]) cube([D + 2 * t + 2 * tab, w, tab_t]);
        }
        translate([0, 0, D / 2 + t]) rotate([90, 0, 0]) cylinder(d = D, h = w + 2, center = true);
        for (s = [-1, 1]) translate([s * (D / 2 + t + tab / 2), 0, 0]) screw_hole(hole, tab_t);
    }
}
rotate(rot) part();
