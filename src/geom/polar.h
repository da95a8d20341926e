/*
 * polar.h - the rotation nearest a 3x3 matrix (signed polar decomposition):
 * R = argmax trace(R^T A) over proper rotations, i.e. U diag(1, 1,
 * det(U V^T)) V^T from the SVD A = U S V^T.  The ARAP local step (Hu 2015,
 * sec. 4.1; Sorkine & Alexa 2007) needs one per tetrahedron per iteration.
 *
 * Two paths, same answer: polar_block() runs scaled Newton iterations
 * (Higham 1986) on POLAR_W matrices at once in structure-of-arrays form,
 * so the compiler vectorizes it; lanes that are reflected (det <= 0),
 * near-singular or slow to converge go to polar_rotation(), a scalar
 * Jacobi eigen-solve of A^T A that handles every case.
 *
 * Pure functions; thread-safe.
 */
#ifndef SF_GEOM_POLAR_H
#define SF_GEOM_POLAR_H

#include "../mesh/vec.h"

/* Lanes per block: 8 doubles fill one AVX-512 register or two AVX2 ones. */
#define POLAR_W 8

/*
 * The block kernels are built for plain x86-64 and, next to it, for
 * x86-64-v3 (AVX2 + FMA) and x86-64-v4 (AVX-512); the loader picks the
 * best one this CPU runs (GNU ifunc), so the binary stays portable
 * without -march=native.  Other compilers and targets get the plain build.
 */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define POLAR_CLONES __attribute__((target_clones("default", "arch=x86-64-v3", "arch=x86-64-v4")))
#else
#define POLAR_CLONES
#endif

/* Nearest proper rotation to a (robust for any a; identity for a = 0). */
struct mat3 polar_rotation(struct mat3 a);

/*
 * r[c][l] = component c (row-major: 3*row + col) of the nearest rotation to
 * the matrix a[.][l], for each lane l < POLAR_W.  Returns how many lanes
 * took the scalar path (for statistics).  a and r may not alias.
 */
int polar_block(const double a[9][POLAR_W], double r[9][POLAR_W]);

#endif
