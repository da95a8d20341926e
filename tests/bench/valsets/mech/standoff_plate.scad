// standoff_plate.scad - a mounting plate (a PCB carrier) on nx x ny
// standoffs: the plate sits sh above the bed on the standoffs as modelled,
// each standoff with a screw hole through it and the plate, and a cable
// slot through the plate.
include <common.scad>
L = 70; W = 50; t = 2.4; sh = 8; sd = 7; hole = 3; nx = 2; ny = 2; r = 3;
slot = 1;
rot = [0, 0, 0];
$fn = 40;

module part() {
    difference() {
        union() {
            translate([0, 0, sh]) rrect(L, W, t, r);
            for (i = [0 : nx - 1], j = [0 : ny - 1])
                translate([(i / max(nx - 1, 1) - 0.5) * (L - sd - 4),
                           (j / max(ny - 1, 1) - 0.5) * (W - sd - 4), 0]) cylinder(d = sd, h = sh + 0.01);
        }
        for (i = [0 : nx - 1], j = [0 : ny - 1])
            translate([(i / max(nx - 1, 1) - 0.5) * (L - sd - 4),
                       (j / max(ny - 1, 1) - 0.5) * (W - sd - 4), 0]) screw_hole(hole, sh + t);
        if (slot) translate([0, 0, sh - 1]) rrect(L / 3, 5, t + 2, 2.4);
    }
}
rotate(rot) part();
