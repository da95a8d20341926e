/*
 * clip_shim.cpp - the extern "C" face of Clipper (see clip_shim.h).
 *
 * Converts struct paths to ClipperLib::Paths and back, runs one operation,
 * and turns exceptions into status codes so nothing C++ crosses the
 * boundary.  Closed results go through a PolyTree so they come out in tree
 * order (outer then its holes).  The vectors Clipper needs are its own
 * business; the results the caller keeps are allocated through mem.h.
 *
 * Thread: reentrant, no shared state.
 */
#include "clip_shim.h"

#include <new>

#include <clipper.hpp>

extern "C" {
#include "../src/base/err.h"
}

using namespace ClipperLib;

static void
to_cl(const struct paths *in, Paths &out)
{
    out.resize(in ? in->n : 0);
    for (uint32_t k = 0; in && k < in->n; k++) {
        Path &p = out[k];
        uint32_t n = paths_len(in, k);
        p.resize(n);
        const struct ipt *q = in->pts + in->start[k];
        for (uint32_t i = 0; i < n; i++)
            p[i] = IntPoint(q[i].x, q[i].y);
    }
}

static bool
add_path(struct paths *out, const Path &p)
{
    if (!paths_begin(out))
        return false;
    for (const IntPoint &q : p) {
        struct ipt v = { q.X, q.Y };
        if (!paths_push(out, v))
            return false;
    }
    return true;
}

/* Outer, its holes, then the islands inside those holes, recursively. */
static bool
from_tree(const PolyNode *node, struct paths *out)
{
    for (const PolyNode *c : node->Childs) {
        if (c->IsOpen())
            continue;
        if (!add_path(out, c->Contour))
            return false;
        for (const PolyNode *h : c->Childs)
            if (!add_path(out, h->Contour))
                return false;
        for (const PolyNode *h : c->Childs)
            if (!from_tree(h, out))
                return false;
    }
    return true;
}

static PolyFillType
fill_of(enum clip_fill f)
{
    return f == CLIP_NONZERO ? pftNonZero : pftEvenOdd;
}

/* out reset, then op (returning a status) run with exceptions turned
   into status codes: SF_ENOMEM for bad_alloc, SF_EBUG for anything else. */
template <typename F>
static int
guarded(struct paths *out, F op)
{
    paths_reset(out);
    try {
        return op();
    } catch (const std::bad_alloc &) {
        return SF_ENOMEM;
    } catch (...) {
        return SF_EBUG;
    }
}

extern "C" int
clip_bool(enum clip_op op, const struct paths *subj, const struct paths *clip, enum clip_fill fill,
          struct paths *out)
{
    return guarded(out, [&]() {
        Paths s, c;
        to_cl(subj, s);
        to_cl(clip, c);
        Clipper cl;
        cl.AddPaths(s, ptSubject, true);
        if (!c.empty())
            cl.AddPaths(c, ptClip, true);
        static const ClipType ct[] = { ctUnion, ctIntersection, ctDifference, ctXor };
        PolyTree tree;
        cl.Execute(ct[op], tree, fill_of(fill), fill_of(fill));
        return from_tree(&tree, out) ? SF_OK : SF_ENOMEM;
    });
}

extern "C" int
clip_offset(const struct paths *in, double delta_mm, enum clip_join join, struct paths *out)
{
    return guarded(out, [&]() {
        Paths s;
        to_cl(in, s);
        static const JoinType jt[] = { jtMiter, jtRound, jtSquare };
        ClipperOffset co(3.0, 0.005 * POLY_SCALE);
        co.AddPaths(s, jt[join], etClosedPolygon);
        PolyTree tree;
        co.Execute(tree, delta_mm * POLY_SCALE);
        return from_tree(&tree, out) ? SF_OK : SF_ENOMEM;
    });
}

extern "C" int
clip_lines(const struct paths *lines, const struct paths *region, struct paths *out)
{
    return guarded(out, [&]() {
        Paths s, c;
        to_cl(lines, s);
        to_cl(region, c);
        Clipper cl;
        cl.AddPaths(s, ptSubject, false);
        cl.AddPaths(c, ptClip, true);
        PolyTree tree;
        cl.Execute(ctIntersection, tree, pftNonZero, pftNonZero);
        Paths open;
        OpenPathsFromPolyTree(tree, open);
        for (const Path &p : open)
            if (p.size() >= 2 && !add_path(out, p))
                return SF_ENOMEM;
        return SF_OK;
    });
}
