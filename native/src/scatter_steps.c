/* The scattering solve's bookkeeping between sweeps, compiled twins of nephele.core.light._passes
 * (_bin_sum, _shot_group) and of the moments' sums in _sweep._sweep: whole-grid
 * passes over (bins, voxels) arrays, each value read and written once, for voxels [v0, v1) (Python
 * runs voxel ranges on its threads).  Rows of the solve's (nb, voxels) arrays are picked by bin
 * index (``bins``), n voxels a row.
 */

#include <stdint.h>
#include <string.h>

#include "scatter_math.h" /* (its GCC vectorizing setting) */

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define CLONES
#endif

#define RUN 1024 /* voxels per run: the float64 sums of a run stay in the first-level cache */

/* out[v] = sum over bins of a[bins[i], v] (float64) */
CLONES
void scatter_bin_sum(int64_t g, const int64_t *bins, const float *a, int64_t n, int64_t v0, int64_t v1, double *out)
{
    for (int64_t c = v0; c < v1; c += RUN) {
        const int64_t e = c + RUN < v1 ? c + RUN : v1;
        double *restrict o = out + c;
        for (int64_t v = 0; v < e - c; v++)
            o[v] = 0.0;
        for (int64_t i = 0; i < g; i++) {
            const float *restrict x = a + bins[i] * n + c;
            for (int64_t v = 0; v < e - c; v++)
                o[v] += x[v];
        }
    }
}

/* After a sweep of bins ``bins``: omega times their unshot light is shot (1 - omega times it stays),
 * what they caught (r, (g, n)) is added to received (or, unless ``inc`` is NULL, written to inc: the
 * pass's increment, which the tail adds at the pass end), and the unshot power per voxel loses omega
 * times ``shot`` and gains albedo times the catch (float64): _shot_group.  (The sweep added what they
 * carried to the total.) */
CLONES
void scatter_shot(int64_t g, const int64_t *bins, int64_t n, int64_t v0, int64_t v1, float *unshot, float *received,
                  float *inc, const float *r, double *power, const double *shot, double albedo, double omega)
{
    const float keep = (float)(1.0 - omega);
    for (int64_t c = v0; c < v1; c += RUN) {
        const int64_t e = c + RUN < v1 ? c + RUN : v1, m = e - c;
        double sum[RUN];
        for (int64_t v = 0; v < m; v++)
            sum[v] = 0.0;
        for (int64_t i = 0; i < g; i++) {
            float *restrict u = unshot + bins[i] * n + c, *restrict rec = received + bins[i] * n + c;
            const float *restrict ri = r + i * n + c;
            for (int64_t v = 0; v < m; v++) {
                u[v] *= keep;
                sum[v] += ri[v];
            }
            if (inc != NULL)
                memcpy(inc + bins[i] * n + c, ri, (size_t)m * sizeof(float));
            else
                for (int64_t v = 0; v < m; v++)
                    rec[v] += ri[v];
        }
        for (int64_t v = 0; v < m; v++)
            power[c + v] = (power[c + v] - omega * shot[c + v]) + albedo * sum[v];
    }
}

/* The moments a sweep caught, per bin (bm (g, nslots, n): first moment along the sweep axis, then
 * the slots kept / m2 / dep where >= 0), added to the unshot light's moments of each set of bins
 * (out (sets, order, 3, n) float64, order 2 with second moments): scale times the sum over bins
 * with weights mw (sets, g); the power a source kept adds its sideways moments (d, m2: (3, n), the
 * profile's centroid and second moment) and the deposits their even sideways spread (1/12); the same
 * sums also to ``also`` where it is not NULL.  The moments' sums of _sweep._sweep. */
/* one set's sums of a run of m voxels from c (acc: its slots) added to out (order, 3, n) */
static inline __attribute__((always_inline)) void add_moments(double *o1, int64_t n, int64_t c, int64_t m,
                                                               int64_t order, int64_t comp, int64_t slot_kept,
                                                               int64_t slot_m2, int64_t slot_dep, const float *d,
                                                               const float *m2, float scale, float acc[][RUN])
{
    for (int64_t v = 0; v < m; v++)
        o1[comp * n + v] += scale * acc[0][v];
    if (slot_kept >= 0)
        for (int64_t x = 0; x < 3; x++)
            for (int64_t v = 0; v < m; v++)
                o1[x * n + v] += d[x * n + c + v] * (scale * acc[slot_kept][v]);
    if (order == 2) {
        double *o2 = o1 + 3 * n;
        for (int64_t v = 0; v < m; v++)
            o2[comp * n + v] += scale * acc[slot_m2][v];
        for (int64_t x = 0; x < 3; x++) {
            if (x == comp)
                continue;
            for (int64_t v = 0; v < m; v++)
                o2[x * n + v] += (1.0f / 12) * (scale * acc[slot_dep][v]);
            if (slot_kept >= 0)
                for (int64_t v = 0; v < m; v++)
                    o2[x * n + v] += m2[x * n + c + v] * (scale * acc[slot_kept][v]);
        }
    }
}

typedef float mom_v8 __attribute__((vector_size(8 * sizeof(float)), aligned(sizeof(float))));
#define TILE 32 /* voxels whose sums over the bins stay in four vector registers */

/* acc[k][v] = the sum over bins b, in order, of mw[b] bm[b, k, c + v] (float32: each product, then
 * its sum), for the slots k and the run's m voxels.  A tile's sums stay in registers over the bins
 * (summed in acc they were loaded and stored again for each bin: the moments of a 16-bin sweep on the
 * Fig. 6 cloud's 128 box, 6 sets, 18.1-18.7 -> 14.9-16.0 ms, the same sums). */
static inline __attribute__((always_inline)) void slot_sums(int64_t g, int64_t nslots, int64_t n, int64_t c, int64_t m,
                                                             const float *mw, const float *bm, float acc[][RUN])
{
    for (int64_t k = 0; k < nslots; k++) {
        const float *x0 = bm + k * n + c;
        int64_t t = 0;
        for (; t + TILE <= m; t += TILE) {
            mom_v8 a0 = {0}, a1 = {0}, a2 = {0}, a3 = {0};
            for (int64_t b = 0; b < g; b++) {
                const float *x = x0 + b * nslots * n + t;
                const float w = mw[b];
                const mom_v8 wv = {w, w, w, w, w, w, w, w};
                a0 += wv * *(const mom_v8 *)x;
                a1 += wv * *(const mom_v8 *)(x + 8);
                a2 += wv * *(const mom_v8 *)(x + 16);
                a3 += wv * *(const mom_v8 *)(x + 24);
            }
            *(mom_v8 *)(acc[k] + t) = a0;
            *(mom_v8 *)(acc[k] + t + 8) = a1;
            *(mom_v8 *)(acc[k] + t + 16) = a2;
            *(mom_v8 *)(acc[k] + t + 24) = a3;
        }
        for (; t < m; t++) {
            float a = 0.0f;
            for (int64_t b = 0; b < g; b++)
                a += mw[b] * x0[b * nslots * n + t];
            acc[k][t] = a;
        }
    }
}

/* one set's sums over voxels [c, c + m) of a run, added to out (and also) */
static inline __attribute__((always_inline)) void set_moments(int64_t g, int64_t nslots, int64_t n, int64_t c,
                                                               int64_t m, const float *mw, const float *bm,
                                                               int64_t order, int64_t comp, int64_t slot_kept,
                                                               int64_t slot_m2, int64_t slot_dep, const float *d,
                                                               const float *m2, float scale, double *o, double *oa)
{
    float acc[4][RUN];
    slot_sums(g, nslots, n, c, m, mw, bm, acc);
    add_moments(o, n, c, m, order, comp, slot_kept, slot_m2, slot_dep, d, m2, scale, acc);
    if (oa != NULL)
        add_moments(oa, n, c, m, order, comp, slot_kept, slot_m2, slot_dep, d, m2, scale, acc);
}

/* Blocks of MB voxels that hold no medium (``held``: a byte per group of 8 voxels from voxel 0, zero
 * where none of them does, _native.held_groups) caught nothing: an empty voxel (tau 0) catches none
 * of a beam and holds no emission.  The runs of blocks between them go alone, and the float64 sums of
 * the empty ones are neither read nor written (58 % of the Fig. 6 cloud's box).  (Found by reading
 * every bin's slots instead, a 16-bin sweep's sums on the 128 box took 14.1-14.4 ms, not 10.9-11.1;
 * with also 18.3-19.9, not 16.5-16.6.)  v0 is a multiple of 8. */
#define MB 32

CLONES
void scatter_moments(int64_t sets, int64_t g, int64_t nslots, int64_t n, int64_t v0, int64_t v1, const float *mw,
                     const float *bm, int64_t comp, int64_t slot_kept, int64_t slot_m2, int64_t slot_dep,
                     const float *d, const float *m2, float scale, double *out, double *also, const uint8_t *held)
{
    const int64_t order = slot_m2 >= 0 ? 2 : 1;
    unsigned char lit[RUN / MB];
    for (int64_t c = v0; c < v1; c += RUN) {
        const int64_t e = c + RUN < v1 ? c + RUN : v1, nblk = (e - c + MB - 1) / MB;
        for (int64_t q = 0; q < nblk; q++) {
            const int64_t b0 = c + q * MB, b1 = b0 + MB < e ? b0 + MB : e;
            unsigned nz = 0;
            for (int64_t h = b0 / 8; h < (b1 + 7) / 8; h++)
                nz |= held[h];
            lit[q] = (unsigned char)(nz != 0);
        }
        for (int64_t q = 0; q < nblk;) {
            if (!lit[q]) {
                q++;
                continue;
            }
            int64_t q1 = q + 1;
            while (q1 < nblk && lit[q1])
                q1++;
            const int64_t s0 = c + q * MB, s1 = c + q1 * MB < e ? c + q1 * MB : e;
            for (int64_t s = 0; s < sets; s++)
                set_moments(g, nslots, n, s0, s1 - s0, mw + s * g, bm, order, comp, slot_kept, slot_m2, slot_dep, d,
                            m2, scale, out + (s * order) * 3 * n + s0,
                            also == NULL ? NULL : also + (s * order) * 3 * n + s0);
            q = q1;
        }
    }
}

/* The voxel profile of a sweep group's unshot light from its moments (mom (order, 3, n) float64 about
 * each voxel's centre, order 2 with second moments) and power p (n,): per axis the exponential's
 * rate kappa (the inverse of _offset, tabulated: rtab, rstep on offsets dlo + i / dscale) and
 * centroid delta, and with second moments the P2 weight q (its excess second moment, held where the
 * source stays >= 0) and the second moment m2; out (2 or 4, 3, n) float32: kappa, delta, m2, q.
 * _solve._Solve.unshot_profile's twin. */
CLONES
void scatter_profile(int64_t n, int64_t v0, int64_t v1, int64_t second, const double *mom, const double *p,
                     const float *rtab, const float *rstep, float dlo, float dhi, float dscale, float *out)
{
    for (int64_t x = 0; x < 3; x++) {
        const double *m1 = mom + x * n, *m2 = mom + (3 + x) * n;
        float *kap = out + x * n, *dl = out + (3 + x) * n, *o2 = out + (6 + x) * n, *oq = out + (9 + x) * n;
        for (int64_t v = v0; v < v1; v++) {
            const double inv = p[v] > 0 ? 1.0 / p[v] : 0.0;
            double dd = m1[v] * inv;
            float dlt = (float)(dd < -0.49 ? -0.49 : dd > 0.49 ? 0.49 : dd);
            float xi = (nph_clampf(dlt, dlo, dhi) - dlo) * dscale;
            int32_t i = (int32_t)xi;
            float k = rtab[i] + (xi - (float)i) * rstep[i];
            kap[v] = k;
            dl[v] = dlt;
            if (!second)
                continue;
            float a = nph_absf(k);
            float e = nph_minf(nph_expf(-a), 0.60653066f), ac = nph_maxf(a, 0.5f);
            float big = 1.0f / (ac * ac) - e / ((1.0f - e) * (1.0f - e));
            float k2 = k * k;
            float series = 1.0f / 12 - k2 * (1.0f / 240 - k2 * (1.0f / 6048));
            float m2e = (a < 0.5f ? series : big) + dlt * dlt;
            double s2 = m2[v] * inv;
            float q = 30.0f * ((float)(s2 < 0.0 ? 0.0 : s2 > 0.25 ? 0.25 : s2) - m2e);
            float am = nph_maxf(a, 1e-6f), half = nph_minf(0.5f * am, 40.0f);
            float lo = -am / nph_expm1f(nph_minf(am, 80.0f));
            float hi = half / ((nph_expf(half) - nph_expf(-half)) * 0.5f) * 2.0f;
            q = p[v] > 0 ? nph_minf(nph_maxf(q, lo), hi) : 0.0f;
            o2[v] = m2e + q / 30.0f;
            oq[v] = q;
        }
    }
}
