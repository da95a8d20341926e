// slot_bridge.scad - a cable guide: a block with n tunnels across it (slots
// of widths from s0 to s1, all sh tall) under a deck t thick: each tunnel's
// roof is a bridge across its slot; a vertical slot pierces the deck.
include <common.scad>
L = 70; W = 20; n = 3; s0 = 6; s1 = 20; sh = 6; t = 2.4; foot = 4;
rot = [0, 0, 0];
$fn = 32;

module part() {
    H = sh + t;
    sw = [for (i = [0 : n - 1]) s0 + (n > 1 ? i * (s1 - s0) / (n - 1) : 0)];
    pitch = (L - foot) / n;
    difference() {
        translate([0, -W / 2, 0]) cube([L, W, H]);
        for (i = [0 : n - 1])
            translate([foot + i * pitch + (pitch - foot - min(sw[i], pitch - foot - 1)) / 2, -W / 2 - 1, -0.01])
                cube([min(sw[i], pitch - foot - 1), W + 2, sh]);
        translate([L / 2, 0, H - t - 1]) rrect(L / 2, 3, t + 2, 1.4);
    }
}
rotate(rot) part();
