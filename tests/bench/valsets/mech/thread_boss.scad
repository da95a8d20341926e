// thread_boss.scad - a threaded boss: a square flange with four screw
// holes and a stud of diameter D with a single-start thread of pitch p (a
// circle off the axis by the thread depth, swept by a twist), h tall, with
// a bore through.  Modelled flange down; rot = [90, 0, 0] lays it on its
// side (the thread and the flange's edge then overhang).
include <common.scad>
D = 16; p = 2; h = 20; flange = 34; ft = 4; bore = 6; hole = 3.4;
rot = [0, 0, 0];
$fn = 48;

module part() {
    depth = p * 0.3;
    difference() {
        union() {
            rrect(flange, flange, ft, 3);
            translate([0, 0, ft - 0.01]) linear_extrude(h, twist = -360 * h / p, slices = ceil(h / p * 16))
                translate([depth / 2, 0]) circle(d = D - depth, $fn = 32);
        }
        translate([0, 0, -1]) cylinder(d = bore, h = h + ft + 2);
        for (sx = [-1, 1], sy = [-1, 1]) translate([sx * (flange / 2 - 4), sy * (flange / 2 - 4), 0]) screw_hole(hole, ft);
    }
}
rotate(rot) part();
