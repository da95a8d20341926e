/*
 * gcheck.c - the job file check of gcheck.h, by rule set.
 *
 * Marlin's rules are read by the Marlin driver's own scanner
 * (drv_marlin_scan), because the driver streams by the same rules and,
 * given no scan, reads the file with it: one reader, so what the check
 * accepts is exactly what the driver sends.  Thread: any.
 */
#include "gcheck.h"

#include "drv.h"
#include "marlin/drv_marlin.h"

const char *
gcheck_rules_name(enum gcheck_rules r)
{
    switch (r) {
    case GCHECK_MARLIN:
        return "marlin";
    }
    return "?";
}

int
gcheck_scan(enum gcheck_rules r, const char *path, struct drv_job_scan *scan, struct sf_err *err)
{
    switch (r) {
    case GCHECK_MARLIN:
        return drv_marlin_scan(path, scan, err);
    }
    return sf_err_set(err, SF_EBUG, "job '%s': G-code rules %d are not known", path, (int)r);
}

int
gcheck_scan_to(enum gcheck_rules r, const char *path, uint64_t first_line,
               struct drv_job_scan *scan, struct sf_err *err)
{
    switch (r) {
    case GCHECK_MARLIN:
        return drv_marlin_scan_to(path, first_line, scan, err);
    }
    return sf_err_set(err, SF_EBUG, "job '%s': G-code rules %d are not known", path, (int)r);
}
