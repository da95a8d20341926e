/*
 * gcjob.h - uploaded G-code as a farm job: what the slicer that wrote it
 * says about its target (the comments PrusaSlicer, OrcaSlicer, Cura and
 * this project's slicer write), and which printers may run it.
 *
 * A G-code job is printed as is: it skips prepare (no orientation, no
 * slicing) and is ready as soon as it is stored and checked.  Its
 * prepared-for key (store.h prep_key, sched.h key) is not a printer's
 * sched_key but "gcode/nNOZZLE/MODEL": the scheduler (sched.c) lets it
 * start on any printer whose farm.ini gcode_models lists MODEL (or "*")
 * and whose nozzle is NOZZLE (when the file states one); the material the
 * file states becomes the job's material, which the scheduler already
 * matches.  A file that names no model runs only on printers with
 * gcode_models "*".
 *
 * Comments read (first value wins; lists take their first element):
 *   model     "; printer_model = X" (PrusaSlicer, OrcaSlicer),
 *             ";TARGET_MACHINE.NAME:X" (Cura, Griffin header)
 *   nozzle    "; nozzle_diameter = 0.4[,0.4]", ";EXTRUDER_TRAIN.0.NOZZLE.DIAMETER:0.4"
 *   material  "; filament_type = PLA[;PETG]", "; material = PLA" (slimfarm's slicer)
 *   flavor    "; gcode_flavor = marlin2", ";FLAVOR:Marlin"
 *   grams     "; filament used [g] = 12.34[, 1.2]" (summed), "; total filament weight [g] : 12.3"
 *   support   "; support material used [g] = 1.2" (slimfarm's slicer)
 * Only the first GCJOB_HEAD_BYTES and last GCJOB_TAIL_BYTES of the file are
 * read (PrusaSlicer and Orca put their config block at the end, Cura its
 * header at the start).
 *
 * Thread: any; pure functions.
 */
#ifndef SF_FARM_GCJOB_H
#define SF_FARM_GCJOB_H

#include <stdbool.h>
#include <stddef.h>

#include "../base/err.h"

#define GCJOB_HEAD_BYTES (256 << 10) /* Cura's header, the start of any file */
#define GCJOB_TAIL_BYTES (512 << 10) /* Orca's config block is ~150 KB, PrusaSlicer's ~40 KB */
#define GCJOB_KEY_PREFIX "gcode/"

/* What a G-code file says about itself; "" / 0 for what it does not say. */
struct gcjob_info {
    char model[64];    /* slicer's printer model */
    char flavor[32];   /* G-code flavor as written */
    char material[32]; /* first extruder's filament type */
    double nozzle_mm;  /* first extruder's nozzle */
    double filament_g; /* filament the slicer estimated, all extruders */
    double support_g;  /* support material the slicer estimated */
};

/*
 * Read the comments of the G-code at path into out.  SF_EIO when it cannot
 * be read; SF_EINVAL when it says it is for firmware no farm driver speaks
 * (flavors UltiGCode, Makerbot/Sailfish, BFB, Mach3), naming the flavor.
 */
int gcjob_read(const char *path, struct gcjob_info *out, struct sf_err *err);

/* Same over bytes in memory (the tests, the fuzzer). */
int gcjob_parse(const char *text, size_t len, struct gcjob_info *out, struct sf_err *err);

/*
 * The print time the head of the G-code at path states ("; estimated
 * printing time [s] = N" in its first GCJOB_EST_HEAD_BYTES: this project's
 * slicer writes it in line 4, and outside tools read it), or -1.  Read once
 * when a job's G-code is made or checked, and kept in the job (store.h
 * est_s); the printer reads the file only for a job stored before that.
 */
#define GCJOB_EST_HEAD_BYTES 4096
double gcjob_estimate_s(const char *path);

/* The prepared-for key of G-code with info g: "gcode/n0.4/MODEL". */
void gcjob_key(const struct gcjob_info *g, char *key, size_t cap);

/* True when key is a G-code job's (gcjob_key), not a printer's sched_key. */
bool gcjob_key_is(const char *key);

/*
 * May a printer with gcode_models and nozzle_mm run G-code of key?  If not
 * and why is not NULL, say why ("runs no uploaded G-code: gcode_models is
 * empty in farm.ini").
 */
bool gcjob_runs_on(const char *key, const char *gcode_models, double nozzle_mm, char *why,
                   size_t why_cap);

#endif
