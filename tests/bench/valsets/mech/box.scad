// box.scad - an enclosure box, open at the top: walls `wall` thick with a
// rebate (the outer half of the wall cut back lip_h at the rim) for a lid's
// lip, snap beads on the inside of the long walls, optional mounting ears at
// mid height (each with a screw hole) and vent slots through a long wall
// (their tops are bridges).
include <common.scad>
L = 80; W = 50; H = 30; wall = 2; floor_t = 1.6; r = 4; lip_h = 3;
snap = 1; ears = 0; vents = 0; vent_w = 12; vent_h = 3;
rot = [0, 0, 0];
$fn = 48;

module part() {
    difference() {
        union() {
            rrect(L, W, H, r);
            if (ears) for (s = [-1, 1])
                translate([s * (L / 2 + 5), 0, H / 2]) rrect(12, 14, 3, 2);
        }
        translate([0, 0, floor_t]) rrect(L - 2 * wall, W - 2 * wall, H, r - wall);
        translate([0, 0, H - lip_h]) difference() {
            rrect(L + 2, W + 2, lip_h + 1, r);
            rrect(L - wall, W - wall, lip_h + 1, r - wall / 2);
        }
        if (ears) for (s = [-1, 1]) translate([s * (L / 2 + 6), 0, H / 2]) screw_hole(3.4, 3);
        if (vents > 0) for (i = [0 : vents - 1])
            translate([(i - (vents - 1) / 2) * (vent_w + 4), -W / 2, floor_t + 4 + vent_h / 2])
                cube([vent_w, 3 * wall, vent_h], center = true);
    }
    if (snap) for (s = [-1, 1])
        translate([0, s * (W / 2 - wall), H - lip_h - 2.5])
            rotate([0, 90, 0]) cylinder(r = 0.8, h = L * 0.4, center = true, $fn = 16);
}
rotate(rot) part();
