/* The scattering solve's shooting step: what a group of bins caught, scattered into every bin's
 * unshot light (nephele.core.light._passes._scatter_into's compiled twin).
 *
 * unshot[i, v] += sum_j mt[j, i] recv[j, v] for voxels v in [v0, v1): mt (k, nb) float32 holds the
 * phase matrix's columns times the albedo, transposed.  Runs of voxels whose k rows of recv fit in
 * the first-level cache (32 kB: 512 voxels for k = 16, 32 for k = 256); in a run, blocks of IB
 * rows of unshot by VB voxels stay in registers while the rows of recv stream past, so each value
 * of unshot is read and written once, and each row of unshot in runs long enough to stream (the
 * 96 rows in 64-byte pieces missed the prefetchers: 2.8 GB/s, slower than NumPy's BLAS).  Python
 * runs voxel ranges on its threads.  Blocks of VB voxels where every row of recv is zero (empty
 * voxels catch nothing: 30 % of the Fig. 6 cloud's blocks of 32 inside its occupied box) are
 * skipped, their rows of unshot neither read nor written: the sum is the same.  VB 32 with the
 * x86-64-v4 clone (32 vector registers hold the 4 x 32 sums): k = 16 2.0-3.0 ms instead of
 * 3.2-4.5 ms on 96 bins x 62928 voxels.
 */

#include <stdint.h>

#include "scatter_math.h" /* (its denormal flush and GCC vectorizing setting) */

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define CLONES
#endif

#define VB 32
#define IB 4

/* rows [i, i + IB) of unshot over voxels [c, c + VB) */
static inline __attribute__((always_inline)) void block(int64_t nb, int64_t k, int64_t i, int64_t c,
                                                        const float *mt, const float *recv, int64_t r_stride,
                                                        float *unshot, int64_t u_stride)
{
    float a0[VB], a1[VB], a2[VB], a3[VB];
    float *u0 = unshot + i * u_stride + c, *u1 = u0 + u_stride, *u2 = u1 + u_stride, *u3 = u2 + u_stride;
    for (int v = 0; v < VB; v++) {
        a0[v] = u0[v];
        a1[v] = u1[v];
        a2[v] = u2[v];
        a3[v] = u3[v];
    }
    for (int64_t j = 0; j < k; j++) {
        const float *restrict r = recv + j * r_stride + c;
        const float *w = mt + j * nb + i;
        const float w0 = w[0], w1 = w[1], w2 = w[2], w3 = w[3];
        for (int v = 0; v < VB; v++) {
            a0[v] += w0 * r[v];
            a1[v] += w1 * r[v];
            a2[v] += w2 * r[v];
            a3[v] += w3 * r[v];
        }
    }
    for (int v = 0; v < VB; v++) {
        u0[v] = a0[v];
        u1[v] = a1[v];
        u2[v] = a2[v];
        u3[v] = a3[v];
    }
}

CLONES
void scatter_shoot(int64_t nb, int64_t k, int64_t v0, int64_t v1, const float *mt, const float *recv,
                   int64_t r_stride, float *unshot, int64_t u_stride)
{
    unsigned csr = nph_flush_denormals();
    int64_t run = (8192 / (k > 0 ? k : 1)) / VB * VB;
    run = run < VB ? VB : run > 512 ? 512 : run;
    int64_t c0 = v0;
    unsigned char lit[512 / VB]; /* per block of the run: does it catch anything */
    for (; c0 + VB <= v1; c0 += run) {
        const int64_t c1 = c0 + run < v1 ? c0 + run : v1 - (v1 - c0) % VB; /* whole VB blocks */
        int64_t any = 0;
        for (int64_t c = c0; c < c1; c += VB) {
            unsigned nz = 0;
            for (int64_t j = 0; j < k && !nz; j++)
                for (int v = 0; v < VB; v++)
                    nz |= recv[j * r_stride + c + v] != 0.0f;
            lit[(c - c0) / VB] = (unsigned char)nz;
            any |= nz;
        }
        int64_t i = 0;
        for (; any && i + IB <= nb; i += IB)
            for (int64_t c = c0; c < c1; c += VB)
                if (lit[(c - c0) / VB])
                    block(nb, k, i, c, mt, recv, r_stride, unshot, u_stride);
        for (; any && i < nb; i++)
            for (int64_t j = 0; j < k; j++)
                for (int64_t v = c0; v < c1; v++)
                    unshot[i * u_stride + v] += mt[j * nb + i] * recv[j * r_stride + v];
        if (c1 < c0 + run) {
            c0 = c1;
            break;
        }
    }
    for (int64_t i = 0; i < nb; i++) /* the last voxels, fewer than VB */
        for (int64_t j = 0; j < k; j++)
            for (int64_t v = c0; v < v1; v++)
                unshot[i * u_stride + v] += mt[j * nb + i] * recv[j * r_stride + v];
    nph_restore_denormals(csr);
}
