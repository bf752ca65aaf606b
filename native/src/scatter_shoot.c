/* The scattering solve's shooting step: what a group of bins caught, scattered into every bin's
 * unshot light (nephele.core.light._passes._scatter_into's compiled twin).
 *
 * unshot[i, v] += sum_j mt[j, i] recv[j, v] for voxels v in [v0, v1): mt (k, nb) float32 holds the
 * phase matrix's columns times the albedo, transposed.  Empty voxels catch nothing, so only groups
 * of GV voxels where some row of recv is not zero are computed (the rest are neither read nor
 * written: the sum is the same).  Inside the Fig. 6 cloud's occupied box 47 % of the groups of 8
 * are lit, 61 % of the blocks of 32 that an earlier version skipped by: 1.17 voxels computed per
 * occupied voxel, not 1.53.  A block is GB lit groups, wherever they lie: rows [i, i + IB) of
 * unshot over its GB x GV voxels stay in registers while the rows of recv stream past (GB vector
 * loads per row, as for GB x GV voxels side by side), so each value of unshot is read and written
 * once per chunk of KC rows of recv.  A run of blocks is as many lit groups as keep their KC rows
 * of recv in the first-level cache (32 kB), and each row of unshot is streamed along the run.
 * Python runs voxel ranges on its threads.  IB x GB = 3 x 4 vectors of sums leave AVX2 room for
 * the row's vector and the broadcast weight (4 x 4 spilled).  Fig. 6 cloud's 128 box (503k voxels,
 * 200k occupied), 96 bins, 2 threads, AMD EPYC: k = 16 27 ms (blocks of 32 voxels: 38 ms), k = 64
 * 94 (105), k = 256 313 (707; NumPy's BLAS on the whole box took the columns from 128 on, 2.4 ms a
 * column: 1.2 now); the solve's products 7.5 -> 5.4 s.
 */

#include <stdint.h>

#include "scatter_math.h" /* (its denormal flush and GCC vectorizing setting) */

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define CLONES
#endif

#define GV 8      /* voxels in a group: one AVX2 vector */
#define GB 4      /* lit groups in a block */
#define IB 3      /* rows of unshot in a block */
#define KC 256    /* rows of recv in a chunk (more: the run's rows would not fit in the cache) */
#define MAXRUN 64 /* lit groups in a run at most */

/* GV floats, read and written where they lie (no alignment).  The helpers below are inlined into
 * scatter_shoot, so each of its clones compiles them for its own instruction set. */
typedef float vec __attribute__((vector_size(GV * sizeof(float)), aligned(sizeof(float))));

/* rows [i, i + IB) of unshot over the G groups at voxel offsets off[0..G) (G constant when inlined):
 * IB x G vectors of sums (16 with AVX2's 16 registers) */
NPH_INLINE void block(int64_t nb, int64_t k, int64_t i, const int64_t *off, const int G, const float *mt,
                      const float *recv, int64_t r_stride, float *unshot, int64_t u_stride)
{
    vec a[IB][GB];
    for (int q = 0; q < IB; q++)
        for (int g = 0; g < G; g++)
            a[q][g] = *(const vec *)(unshot + (i + q) * u_stride + off[g]);
    /* the next block's rows of unshot asked for now: the lit groups lie apart, 96 rows 2 MB from one
     * another, and the hardware prefetcher does not follow them (128 box: k = 16 26-27 -> 22-23 ms,
     * k = 64 79-84 -> 75, k = 256 275 -> 260-265; two rows on, no better) */
    if (i + 2 * IB <= nb)
        for (int q = 0; q < IB; q++)
            for (int g = 0; g < G; g++)
                __builtin_prefetch(unshot + (i + IB + q) * u_stride + off[g], 1);
    for (int64_t j = 0; j < k; j++) {
        const float *w = mt + j * nb + i;
        for (int g = 0; g < G; g++) {
            const vec r = *(const vec *)(recv + j * r_stride + off[g]);
            for (int q = 0; q < IB; q++)
                a[q][g] += w[q] * r;
        }
    }
    for (int q = 0; q < IB; q++)
        for (int g = 0; g < G; g++)
            *(vec *)(unshot + (i + q) * u_stride + off[g]) = a[q][g];
}

/* unshot[i, v] += sum_j mt[j, i] recv[j, v] for one voxel v, rows of unshot from i on */
NPH_INLINE void one_voxel(int64_t nb, int64_t k, int64_t i, int64_t v, const float *mt, const float *recv,
                          int64_t r_stride, float *unshot, int64_t u_stride)
{
    for (; i < nb; i++) {
        float s = unshot[i * u_stride + v];
        for (int64_t j = 0; j < k; j++)
            s += mt[j * nb + i] * recv[j * r_stride + v];
        unshot[i * u_stride + v] = s;
    }
}

/* rows [0, nb) of unshot over the lit groups off[0..n), k rows of recv */
NPH_INLINE void run_groups(int64_t nb, int64_t k, const int64_t *off, int64_t n, const float *mt, const float *recv,
                           int64_t r_stride, float *unshot, int64_t u_stride)
{
    const int64_t whole = n - n % GB;
    int64_t i = 0;
    for (; i + IB <= nb; i += IB) {
        for (int64_t g = 0; g < whole; g += GB)
            block(nb, k, i, off + g, GB, mt, recv, r_stride, unshot, u_stride);
        for (int64_t g = whole; g < n; g++)
            block(nb, k, i, off + g, 1, mt, recv, r_stride, unshot, u_stride);
    }
    for (int64_t g = 0; g < n && i < nb; g++) /* rows left after the blocks of IB */
        for (int v = 0; v < GV; v++)
            one_voxel(nb, k, i, off[g] + v, mt, recv, r_stride, unshot, u_stride);
}

/* does some of the k rows of recv hold anything on voxels [c, c + GV) */
NPH_INLINE int lit(int64_t k, int64_t c, const float *recv, int64_t r_stride)
{
    for (int64_t j = 0; j < k; j++) {
        unsigned nz = 0;
        for (int v = 0; v < GV; v++)
            nz |= recv[j * r_stride + c + v] != 0.0f;
        if (nz)
            return 1;
    }
    return 0;
}

/* ``held`` (NULL: none) has a byte per group of GV voxels from voxel 0, zero where no voxel of the group
 * holds any medium: such a group catches nothing (tau 0), so it is skipped without reading its rows
 * of recv (lit reads all k of an empty group's rows, each in a cache line of its own: about a tenth of
 * the products' time inside the Fig. 6 cloud's box). */
CLONES
void scatter_shoot(int64_t nb, int64_t k, int64_t v0, int64_t v1, const float *mt, const float *recv,
                   int64_t r_stride, float *unshot, int64_t u_stride, const uint8_t *held)
{
    unsigned csr = nph_flush_denormals();
    for (int64_t j0 = 0; j0 < k; j0 += KC) {
        const int64_t kc = k - j0 < KC ? k - j0 : KC;
        const float *m = mt + j0 * nb, *r = recv + j0 * r_stride;
        int64_t most = 8192 / (kc * GV);
        most = most < GB ? GB : most > MAXRUN ? MAXRUN : most;
        int64_t off[MAXRUN], n = 0, c = v0;
        for (; c + GV <= v1; c += GV) {
            if ((held == NULL || held[c / GV]) && lit(kc, c, r, r_stride))
                off[n++] = c;
            if (n == most) {
                run_groups(nb, kc, off, n, m, r, r_stride, unshot, u_stride);
                n = 0;
            }
        }
        run_groups(nb, kc, off, n, m, r, r_stride, unshot, u_stride);
        for (; c < v1; c++) /* the last voxels, fewer than GV */
            one_voxel(nb, kc, 0, c, m, r, r_stride, unshot, u_stride);
    }
    nph_restore_denormals(csr);
}
