// lid.scad - the lid for box.scad: a plate t thick with a lip (lip_w wide,
// lip_h tall) that fits inside the box's rebate, snap bumps on the lip's
// outside, and a finger recess in the plate's top.  Modelled plate down,
// lip up; rot = [180, 0, 0] is the lid uploaded lip-down.
include <common.scad>
L = 80; W = 50; t = 2; r = 4; lip_h = 3; lip_w = 1.2; wall = 2; gap = 0.2;
snap = 1; recess = 1;
rot = [0, 0, 0];
$fn = 48;

module part() {
    il = L - wall - 2 * gap;  // lip outside: the box's rebate less a gap
    iw = W - wall - 2 * gap;
    difference() {
        union() {
            rrect(L, W, t, r);
            translate([0, 0, t - 0.01]) difference() {
                rrect(il, iw, lip_h, r - wall / 2);
                translate([0, 0, -0.01]) rrect(il - 2 * lip_w, iw - 2 * lip_w, lip_h + 1, r - wall);
            }
        }
        if (recess) translate([0, -W / 2 + 6, -0.01]) rrect(16, 6, min(0.8, t / 2), 3);
    }
    if (snap) for (s = [-1, 1])
        translate([0, s * iw / 2, t + lip_h - 1.2])
            rotate([0, 90, 0]) cylinder(r = 0.6, h = il * 0.3, center = true, $fn = 16);
}
rotate(rot) part();
