/*
 * gcode3mf.h - wrap our G-code in the ".gcode.3mf" a Bambu Lab printer
 * prints (Bambu Studio's "Export plate sliced file"): a 3MF package with
 * no geometry whose Metadata/plate_1.gcode is the job.
 *
 * Entries written (../shared/BAMBU-LAN.md section 1): [Content_Types].xml,
 * _rels/.rels, 3D/3dmodel.model (no mesh), Metadata/plate_1.gcode,
 * Metadata/plate_1.gcode.md5 (uppercase hex MD5 of the G-code, no newline:
 * a mismatch is HMS 0500-4003 on a P1S), Metadata/model_settings.config
 * with Metadata/_rels/model_settings.config.rels, Metadata/slice_info.config
 * and Metadata/plate_1.json.  No thumbnails and no project_settings.config
 * (no source says the firmware reads them; Bambu Connect wants them).
 *
 * The G-code is copied in steps (gcode3mf_step), so a driver can pack a
 * 150 MB job on the loop thread a megabyte per turn without stalling it.
 *
 * Thread: any, one writer per thread.  The writer owns its zip handle and
 * its open G-code file; gcode3mf_free releases both (and removes a partial
 * output).
 */
#ifndef SF_DRIVERS_BAMBU_GCODE3MF_H
#define SF_DRIVERS_BAMBU_GCODE3MF_H

#include <stddef.h>
#include <stdint.h>

#include "../../src/base/err.h"

struct gcode3mf_meta {
    const char *title;  /* shown on the printer (slice_info), ASCII; NULL: "slimfarm" */
    double print_s;     /* predicted print time, s (0: unknown) */
    double filament_g;  /* predicted filament, g (0: unknown) */
    double nozzle_mm;   /* nozzle diameter (0: 0.4) */
    const char *client; /* X-BBL-Client-Type header value; NULL: "slimfarm" */
};

struct gcode3mf;

/*
 * Start writing out_path from the G-code file gcode_path.  NULL with err
 * set: SF_EIO (a file cannot be opened or created), SF_EINVAL (bad meta).
 */
struct gcode3mf *gcode3mf_new(const char *out_path, const char *gcode_path,
                              const struct gcode3mf_meta *meta, struct sf_err *err);
/*
 * Copy up to max_bytes more G-code (0: all).  Returns 1 when more is left,
 * 0 when the package is complete and closed, or SF_EIO / SF_ENOMEM.
 */
int gcode3mf_step(struct gcode3mf *w, size_t max_bytes, struct sf_err *err);
/* Bytes of G-code copied so far, and the G-code file's size. */
uint64_t gcode3mf_done(const struct gcode3mf *w);
uint64_t gcode3mf_total(const struct gcode3mf *w);
/* The G-code's MD5 as 32 uppercase hex digits; valid once step returned 0. */
const char *gcode3mf_gcode_md5(const struct gcode3mf *w);
/* Free; a package not completed is removed.  NULL is fine. */
void gcode3mf_free(struct gcode3mf *w);

/* One call: gcode3mf_new, step to the end, free.  md5_out (33 bytes) or NULL. */
int gcode3mf_write(const char *out_path, const char *gcode_path, const struct gcode3mf_meta *meta,
                   char *md5_out, struct sf_err *err);

/*
 * MD5 of a whole file as 32 uppercase hex digits into out (33 bytes): the
 * project_file command's "md5" field is the package's.  SF_EIO.
 */
int gcode3mf_file_md5(const char *path, char *out, struct sf_err *err);

#endif
