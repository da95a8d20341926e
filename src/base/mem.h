/*
 * mem.h - checked allocation.
 *
 * Every allocation in slimfarm goes through here so that (1) array sizes are
 * multiplied with an overflow check, never by hand, and (2) tests can make
 * the Nth allocation fail: with SLIMFARM_FAIL_ALLOC=N in the environment (or
 * mem_fail_after(N) from a test) allocation number N and every later one
 * return NULL, as in curl's torture mode and SQLite's OOM tests.  The
 * functions return NULL on failure and never abort; callers turn NULL into
 * SF_ENOMEM.  Memory is freed with plain free().
 *
 * Thread-safe: the failure counter is atomic.
 */
#ifndef SF_BASE_MEM_H
#define SF_BASE_MEM_H

#include <stdbool.h>
#include <stddef.h>

/* malloc(size); NULL on failure or injected failure. */
void *mem_alloc(size_t size);

/* calloc(n, size) with overflow check: zeroed memory or NULL. */
void *mem_calloc(size_t n, size_t size);

/* malloc(n * size) with overflow check, not zeroed. */
void *mem_array(size_t n, size_t size);

/*
 * realloc(p, n * size) with overflow check.  On failure returns NULL and
 * leaves p allocated and unchanged.
 */
void *mem_realloc_array(void *p, size_t n, size_t size);

/* strdup(s) through the checked allocator. */
char *mem_strdup(const char *s);

/* strndup(s, n) through the checked allocator. */
char *mem_strndup(const char *s, size_t n);

/*
 * Grow *p (an array of *cap elements of elem_size) so it holds at least
 * need elements, doubling; returns false (and leaves *p, *cap) on failure.
 */
bool mem_grow(void **p, size_t *cap, size_t need, size_t elem_size);

/*
 * Tune the C library's allocator for a short-lived batch process (one CLI
 * command): freed blocks stay in the heap for reuse instead of going back
 * to the kernel, every thread shares the one heap, and the heap (heap_mb
 * megabytes are reserved up front) is backed by transparent huge pages
 * where the kernel allows it (THP "madvise" mode).  A first touch of a
 * 4 KB page costs a page fault of 14-24 us on the farm's VMs; a 2 MB page
 * is one fault.  Never call it in the daemon: its memory would not shrink.
 * Best effort: anything the system refuses is left as it was.
 */
void mem_batch_mode(size_t heap_mb);

/* True when a * b would overflow size_t. */
bool mem_mul_overflows(size_t a, size_t b);

/*
 * Test hooks: make allocation number n (1-based, counted from this call)
 * and all after it fail; n = 0 turns injection off.  mem_alloc_count()
 * reports how many allocations were attempted since the last call.
 */
void mem_fail_after(long n);
long mem_alloc_count(void);

#endif
