// boss_block.scad - a base plate with n vertical screw bosses (counterbored
// holes), a rib between them, and an upright wall carrying a horizontal
// boss with a bore (its underside overhangs).
include <common.scad>
L = 60; W = 40; t = 3; n = 3; bd = 9; bh = 12; hole = 3.2; wall_h = 25; hb_d = 10; hb_len = 12;
rot = [0, 0, 0];
$fn = 40;

module part() {
    difference() {
        union() {
            rrect(L, W, t, 3);
            for (i = [0 : n - 1]) translate([(i / max(n - 1, 1) - 0.5) * (L - bd - 6), -W / 4, 0])
                cylinder(d = bd, h = bh);
            translate([-(L - bd - 6) / 2, -W / 4 - 1, 0]) cube([L - bd - 6, 2, bh * 0.6]);
            // the wall stands inside the plate's outline: an edge shared with the
            // plate's rounded corner would come out of OpenSCAD as a zero-area
            // sliver triangle
            translate([-L / 2 + 3, W / 2 - 5, 0]) cube([L - 6, 4, wall_h]);
            translate([0, W / 2 - 3, wall_h * 0.6]) rotate([90, 0, 0]) cylinder(d = hb_d, h = hb_len + 2);
        }
        for (i = [0 : n - 1]) translate([(i / max(n - 1, 1) - 0.5) * (L - bd - 6), -W / 4, 0])
            screw_hole(hole, bh, hole * 1.9, 2);
        translate([0, W / 2 + 1, wall_h * 0.6]) rotate([90, 0, 0]) cylinder(d = hole, h = hb_len + 6);
    }
}
rotate(rot) part();
