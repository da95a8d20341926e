// bore_block.scad - a pillow block: a base with two counterbored mounting
// holes and a raised body with a horizontal bore (d) along x, round or a
// teardrop (top at 45 degrees, printable without support), plus a smaller
// cross bore along y.
include <common.scad>
L = 50; W = 24; H = 30; d = 12; base_t = 6; teardrop = 0; hole = 4.2; cross_d = 4;
rot = [0, 0, 0];
$fn = 48;

module part() {
    cz = H - d / 2 - 4;
    difference() {
        union() {
            translate([-L / 2, -W / 2, 0]) cube([L, W, base_t]);
            translate([-(d / 2 + 5), -W / 2, 0]) cube([d + 10, W, H]);
        }
        translate([0, 0, cz]) rotate([0, 0, 90]) hbore(d, W + 2, teardrop);
        translate([0, 0, cz - d / 2 - 3]) hbore(cross_d, d + 12, teardrop);
        for (s = [-1, 1]) translate([s * (L / 2 - 6), 0, 0]) screw_hole(hole, base_t, hole * 1.8, 2);
    }
}
rotate(rot) part();
