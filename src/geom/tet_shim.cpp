/*
 * tet_shim.cpp - TetGen 1.5 behind extern "C" (see tet_shim.h).
 *
 * Why a shim: TetGen is a C++ class library and signals errors by
 * throwing an int (Debian builds it with TETLIBRARY); the rest of
 * slimfarm is C11.  The shim copies the surface into a tetgenio, runs
 * tetrahedralize() with the caller's switches plus 'z' (zero-based) and
 * 'Q' (quiet), and copies points and tets out into mem.h arrays, so no
 * TetGen memory escapes.  Every exception becomes an sf_status.
 *
 * Thread: any; each call owns its tetgenio objects.
 */
#include "tet_shim.h"

#include <cstdlib>
#include <cstring>
#include <new>
#include <string>
#define TETLIBRARY
#include <tetgen.h>

extern "C" {
#include "../base/err.h"
#include "../base/mem.h"
}

static const char *
tetgen_reason(int code)
{
    switch (code) {
    case 1:
        return "out of memory";
    case 2:
        return "internal error";
    case 3:
        return "a self-intersection was found in the surface";
    case 4:
        return "a very small input feature size was found";
    case 5:
        return "two very close input facets were found";
    case 10:
        return "an input error was found";
    default:
        return "unknown error";
    }
}

extern "C" int
tet_shim_tetrahedralize(const double *xyz, uint32_t n_points, const uint32_t *tris, uint32_t n_tris,
                        const char *switches, struct tet_shim_out *out, struct sf_err *err)
{
    std::memset(out, 0, sizeof(*out));
    if (n_points < 4 || n_tris < 4)
        return sf_err_set(err, SF_EINVAL, "tetgen: a closed surface needs at least 4 triangles");
    try {
        tetgenio in, res;
        in.firstnumber = 0;
        in.numberofpoints = (int)n_points;
        in.pointlist = new REAL[3 * (size_t)n_points];
        std::memcpy(in.pointlist, xyz, sizeof(double) * 3 * n_points);
        in.numberoffacets = (int)n_tris;
        in.facetlist = new tetgenio::facet[n_tris];
        for (uint32_t i = 0; i < n_tris; i++) {
            tetgenio::facet *f = &in.facetlist[i];
            tetgenio::init(f);
            f->numberofpolygons = 1;
            f->polygonlist = new tetgenio::polygon[1];
            tetgenio::init(&f->polygonlist[0]);
            f->polygonlist[0].numberofvertices = 3;
            f->polygonlist[0].vertexlist = new int[3];
            for (int k = 0; k < 3; k++)
                f->polygonlist[0].vertexlist[k] = (int)tris[3 * (size_t)i + k];
        }
        std::string sw = std::string(switches ? switches : "p") + "zQ";
        tetrahedralize(&sw[0], &in, &res);
        if (res.numberofpoints <= 0 || res.numberoftetrahedra <= 0 || res.numberofcorners != 4)
            return sf_err_set(err, SF_EINVAL, "tetgen: no tetrahedra produced");
        out->xyz = (double *)mem_array((size_t)res.numberofpoints, 3 * sizeof(double));
        out->tets = (uint32_t *)mem_array((size_t)res.numberoftetrahedra, 4 * sizeof(uint32_t));
        if (!out->xyz || !out->tets) {
            tet_shim_release(out);
            return sf_err_set(err, SF_ENOMEM, "tetgen: out of memory copying %d tetrahedra",
                              res.numberoftetrahedra);
        }
        std::memcpy(out->xyz, res.pointlist, sizeof(double) * 3 * (size_t)res.numberofpoints);
        for (size_t i = 0; i < 4 * (size_t)res.numberoftetrahedra; i++)
            out->tets[i] = (uint32_t)res.tetrahedronlist[i];
        out->n_points = (uint32_t)res.numberofpoints;
        out->n_tets = (uint32_t)res.numberoftetrahedra;
        return SF_OK;
    } catch (const std::bad_alloc &) {
        tet_shim_release(out);
        return sf_err_set(err, SF_ENOMEM, "tetgen: out of memory");
    } catch (int code) {
        tet_shim_release(out);
        return sf_err_set(err, code == 1 ? SF_ENOMEM : SF_EINVAL, "tetgen: %s (code %d)",
                          tetgen_reason(code), code);
    } catch (...) {
        tet_shim_release(out);
        return sf_err_set(err, SF_EBUG, "tetgen: unexpected exception");
    }
}

extern "C" void
tet_shim_release(struct tet_shim_out *out)
{
    free(out->xyz);
    free(out->tets);
    std::memset(out, 0, sizeof(*out));
}
