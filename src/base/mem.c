/*
 * mem.c - checked allocation with failure injection (see mem.h).
 *
 * The counter is consulted only when injection is armed, so the normal path
 * costs one relaxed atomic load.  SLIMFARM_FAIL_ALLOC is read once, at the
 * first allocation.
 */
#include "mem.h"

#include <malloc.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

static atomic_long fail_at = -1; /* -1: env not read yet; 0: off */
static atomic_long alloc_count;

static bool
should_fail(void)
{
    long at = atomic_load_explicit(&fail_at, memory_order_relaxed);
    if (at < 0) {
        const char *env = getenv("SLIMFARM_FAIL_ALLOC");
        long n = env ? strtol(env, NULL, 10) : 0;
        long expect = -1;
        atomic_compare_exchange_strong(&fail_at, &expect, n > 0 ? n : 0);
        at = atomic_load(&fail_at);
    }
    long count = atomic_fetch_add_explicit(&alloc_count, 1, memory_order_relaxed) + 1;
    return at > 0 && count >= at;
}

bool
mem_mul_overflows(size_t a, size_t b)
{
    return b != 0 && a > SIZE_MAX / b;
}

void *
mem_alloc(size_t size)
{
    if (should_fail())
        return NULL;
    return malloc(size ? size : 1);
}

void *
mem_calloc(size_t n, size_t size)
{
    if (mem_mul_overflows(n, size) || should_fail())
        return NULL;
    return calloc(n ? n : 1, size ? size : 1);
}

void *
mem_array(size_t n, size_t size)
{
    if (mem_mul_overflows(n, size))
        return NULL;
    return mem_alloc(n * size);
}

void *
mem_realloc_array(void *p, size_t n, size_t size)
{
    if (mem_mul_overflows(n, size) || should_fail())
        return NULL;
    size_t bytes = n * size;
    return realloc(p, bytes ? bytes : 1);
}

char *
mem_strdup(const char *s)
{
    return mem_strndup(s, strlen(s));
}

char *
mem_strndup(const char *s, size_t n)
{
    size_t len = strnlen(s, n);
    char *d = mem_alloc(len + 1);
    if (!d)
        return NULL;
    memcpy(d, s, len);
    d[len] = '\0';
    return d;
}

bool
mem_grow(void **p, size_t *cap, size_t need, size_t elem_size)
{
    if (need <= *cap)
        return true;
    size_t ncap = *cap ? *cap : 16;
    while (ncap < need) {
        if (ncap > SIZE_MAX / 2)
            return false;
        ncap *= 2;
    }
    void *np = mem_realloc_array(*p, ncap, elem_size);
    if (!np)
        return false;
    *p = np;
    *cap = ncap;
    return true;
}

void
mem_fail_after(long n)
{
    atomic_store(&alloc_count, 0);
    atomic_store(&fail_at, n > 0 ? n : 0);
}

long
mem_alloc_count(void)
{
    return atomic_exchange(&alloc_count, 0);
}

void
mem_batch_mode(size_t heap_mb)
{
    const uintptr_t huge = 2u << 20;
    size_t pad = heap_mb << 20;
    /* blocks up to 256 MB come from the heap (glibc maps anything over 128 KB afresh
       by default, and unmaps it on free) */
    mallopt(M_MMAP_THRESHOLD, 256 << 20);
    mallopt(M_TRIM_THRESHOLD, INT32_MAX);
    mallopt(M_TOP_PAD, pad > INT32_MAX ? INT32_MAX : (int)pad);
    mallopt(M_ARENA_MAX, 1); /* threads' arenas would be fresh, unadvised mappings */
    /* Grow the heap now, by the pad, and advise the whole of it.  (The heap is
       one mapping grown by brk; a later growth would not inherit the advice.) */
    char *lo = sbrk(0);
    void *volatile probe = malloc(1 << 20); /* volatile: the pair is not optimised out */
    free(probe);
    char *hi = sbrk(0);
    uintptr_t start = ((uintptr_t)lo + huge - 1) & ~(huge - 1);
    if (lo != (char *)-1 && hi != (char *)-1 && (uintptr_t)hi > start + huge)
        madvise((void *)start, (uintptr_t)hi - start, MADV_HUGEPAGE);
}
