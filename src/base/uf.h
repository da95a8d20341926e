/*
 * uf.h - union-find over uint32_t indices in a caller's parent array
 * (par[i] == i for a root), with path halving.  No allocation.
 */
#ifndef SF_BASE_UF_H
#define SF_BASE_UF_H

#include <stdbool.h>
#include <stdint.h>

static inline uint32_t
uf_find(uint32_t *par, uint32_t x)
{
    while (par[x] != x)
        x = par[x] = par[par[x]];
    return x;
}

/* Join the sets of a and b; returns whether they were apart. */
static inline bool
uf_union(uint32_t *par, uint32_t a, uint32_t b)
{
    a = uf_find(par, a);
    b = uf_find(par, b);
    if (a == b)
        return false;
    par[a] = b;
    return true;
}

#endif
