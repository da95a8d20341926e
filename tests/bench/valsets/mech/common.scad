// common.scad - shapes shared by the mech templates (include <common.scad>).
// Units mm; z up; parts are built resting on z = 0 as designed and the
// generator turns them by `rot` (the orientation a user uploads them in).

// a rounded rectangle l x w, corner radius r, extruded h (centred in x, y)
module rrect(l, w, h, r) {
    rr = max(min(r, min(l, w) / 2 - 0.01), 0.01);
    linear_extrude(h) offset(r = rr) square([l - 2 * rr, w - 2 * rr], center = true);
}

// a horizontal hole along x through length len, diameter d, centred at the
// origin; teardrop = 1 points its top at 45 degrees (printable unsupported)
module hbore(d, len, teardrop = 0) {
    rotate([0, 90, 0]) rotate([0, 0, 90]) linear_extrude(len, center = true) {
        circle(d = d);
        if (teardrop) rotate(45) square(d / 2);
    }
}

// a vertical screw hole of diameter d through height h, with a counterbore
// (cd wide, cdepth deep) at the top when cd > 0
module screw_hole(d, h, cd = 0, cdepth = 0) {
    translate([0, 0, -0.01]) cylinder(d = d, h = h + 0.02);
    if (cd > 0) translate([0, 0, h - cdepth]) cylinder(d = cd, h = cdepth + 0.01);
}
