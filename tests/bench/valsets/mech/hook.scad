// hook.scad - a wall hook: a back plate (ph tall, t thick, w wide) with two
// countersunk holes, an arm reaching out `reach` from arm_z of the plate's
// height and a tip rising `tip`: modelled as it hangs on the wall (the
// arm's underside overhangs).
include <common.scad>
ph = 60; t = 4; w = 18; reach = 30; tip = 14; r_in = 6; hole = 4; arm_z = 0.3;
rot = [0, 0, 0];
$fn = 40;

module profile() {
    az = ph * arm_z;
    square([t, ph]);                                     // back plate
    translate([0, az]) square([reach, t]);               // arm
    translate([reach - t, az]) square([t, tip]);         // tip
    translate([t, az + t]) difference() { square(r_in); translate([r_in, r_in]) circle(r_in); }
}
module part() {
    difference() {
        rotate([90, 0, 0]) translate([0, 0, -w / 2]) linear_extrude(w) profile();
        for (z = [ph * 0.45, ph * 0.8]) translate([0, 0, z]) rotate([0, 90, 0]) {
            translate([0, 0, -1]) cylinder(d = hole, h = t + 2);
            translate([0, 0, t - hole / 2]) cylinder(d1 = hole, d2 = hole * 2 + 0.1, h = hole / 2 + 0.01);
        }
    }
}
rotate(rot) part();
