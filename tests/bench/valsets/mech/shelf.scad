// shelf.scad - a small wall shelf: a back plate with two screw holes, a
// shelf board sticking out `depth` at the top, nb triangular braces below
// it and a front lip: modelled as it hangs (the board's underside between
// the braces overhangs).
include <common.scad>
L = 90; depth = 40; back_h = 45; t = 3; nb = 2; lip = 4; hole = 4;
rot = [0, 0, 0];
$fn = 32;

module part() {
    difference() {
        union() {
            translate([-L / 2, 0, 0]) cube([L, t, back_h]);
            translate([-L / 2, 0, back_h - t]) cube([L, depth, t]);
            translate([-L / 2, depth - t, back_h - 0.01]) cube([L, t, lip]);
            for (i = [0 : nb - 1])
                translate([(nb > 1 ? (i / (nb - 1) - 0.5) * (L - 3 * t) : 0) - t / 2, 0, 0])
                    rotate([90, 0, 90]) linear_extrude(t)
                        polygon([[t - 0.01, back_h * 0.3], [t - 0.01, back_h - t + 0.01], [depth * 0.8, back_h - t + 0.01]]);
        }
        for (s = [-1, 1]) translate([s * L / 4, -1, back_h * 0.4]) rotate([-90, 0, 0]) cylinder(d = hole, h = t + 2);
    }
}
rotate(rot) part();
