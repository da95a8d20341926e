/*
 * test_cancel.c - the long stages of prepare stop on the job's cancel flag
 * (issue 16 item 7): orientation checks it before each direction it scores.
 * (slim, surface and slice are covered in their own tests.)
 */
#include <stdatomic.h>

#include "../../src/geom/orient.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

T_CASE(orient_find_stops_on_cancel)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    struct orient_params p;
    orient_params_default(&p);
    p.threads = 2;
    atomic_bool cancel = true;
    p.cancel = &cancel;
    struct orient_result r;
    T_ERR(orient_find(&m, &p, &r, &err), SF_ECANCELED, &err, "cancelled");
    atomic_store(&cancel, false); /* and runs to the end when not cancelled */
    T_OK(orient_find(&m, &p, &r, &err), &err);
    mesh_release(&m);
}
