/* The views' plane march: emission-absorption along camera rays through the planes of a
 * scattering solution's view (nephele.core.light._views._march_rays' compiled twin, the same
 * operations in the same order but for the float32 exponentials of scatter_math.h).
 *
 * Sample s is a plane of complex texels (sigma, source) at texel coordinate xs[s] along the march
 * axis, rows of nbp texels; ray r meets it at texel coordinates (a0 + a1 x, b0 + b1 x), clipped to
 * the plane, and takes the bilinear of the four texels around that point.  Its segment, of optical
 * depth tau = -ns sigma, adds T S (1 - e^-tau) / tau (times the step, which the caller applies) to
 * its sum, and its transmittance T falls by e^-tau.  Ray r is marched over samples start[r] to
 * end[r] (rays sorted by start) in blocks of ``block`` samples, as the twin marches them: at each
 * block's start the rays past their last sample leave and those starting in the block join, so a
 * ray is marched on the whole blocks its span touches (the samples outside its span meet zero
 * texels: they add exact zeros).  Sample by sample, over the rays in flight: the sample's plane
 * stays in the cache while they read it (a ray marched through all its samples at once would read
 * another plane at each: 27 MB of planes in the 128x128x96 cloud's view).  Python runs jobs of rays
 * on its threads.
 */

#include <stdint.h>

#include "scatter_math.h"

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define CLONES
#endif

/* The rays in flight: their coefficients, sums and transmittances side by side (k of them), and
 * for the sample at hand each one's texel (its bilinear's first, as an offset into the plane's
 * floats) and bilinear weights. */
struct flight {
    double *a0, *a1, *b0, *b1;
    float *ns, *acc, *tr, *fa, *fb;
    int32_t *q;
};

/* One sample's plane ``p`` at texel coordinate x, for the k rays in flight: where each ray meets it
 * (float64, as the twin), then the bilinear and the segment's light (float32).  Two loops, so that
 * the compiler makes vectors of both (the second gathers the texels: in one loop neither was). */
NPH_INLINE void march_sample(const float *restrict p, int64_t nbp, double x, double lim_a, double lim_b,
                             const struct flight *f, int64_t k)
{
    const double *restrict a0 = f->a0, *restrict a1 = f->a1, *restrict b0 = f->b0, *restrict b1 = f->b1;
    const float *restrict ns = f->ns;
    float *restrict acc = f->acc, *restrict tr = f->tr, *restrict fa = f->fa, *restrict fb = f->fb;
    int32_t *restrict qs = f->q;
    const int32_t row = (int32_t)(2 * nbp);
    for (int64_t j = 0; j < k; j++) {
        double ua = a1[j] * x;
        ua += a0[j];
        ua = ua > 0.0 ? ua : 0.0;
        ua = ua < lim_a ? ua : lim_a;
        double ub = b1[j] * x;
        ub += b0[j];
        ub = ub > 0.0 ? ub : 0.0;
        ub = ub < lim_b ? ub : lim_b;
        const int32_t ia = (int32_t)ua, ib = (int32_t)ub; /* >= 0: the floor */
        fa[j] = (float)(ua - ia);
        fb[j] = (float)(ub - ib);
        qs[j] = ia * row + 2 * ib;
    }
    for (int64_t j = 0; j < k; j++) {
        const int32_t q = qs[j];
        /* bilinear: along b on both rows, then along a (the twin's complex64 steps, part by part) */
        float vr = p[q], vi = p[q + 1];
        float tr_ = p[q + 2] - vr, ti = p[q + 3] - vi;
        vr += tr_ * fb[j];
        vi += ti * fb[j];
        float wr = p[q + row], wi = p[q + row + 1];
        tr_ = p[q + row + 2] - wr;
        ti = p[q + row + 3] - wi;
        wr += tr_ * fb[j];
        wi += ti * fb[j];
        wr -= vr;
        wi -= vi;
        vr += wr * fa[j];
        vi += wi * fa[j];
        const float tau = vr * ns[j], t = nph_minf(tau, -NPH_TINY); /* -tau; at 0, -tiny / -tiny */
        float e = nph_expf(tau), phi = nph_expm1f(t) / t;          /* (1 - e^-tau) / tau, 1 at tau = 0 */
        phi *= vi;
        phi *= tr[j];
        acc[j] += phi;
        tr[j] *= e;
    }
}

/* Ray r of the job: coefficients coef[0..3][r] (a0, a1, b0, b1) and minus its step ns[r]; samples
 * start[r] to end[r], rays sorted by start, the march beginning at sample ``first``.  Writes each
 * ray's sum acc[r] and transmittance tr[r].  Work: act (n int64), dwork (4 n float64), fwork (5 n
 * float32), qwork (n int32); a plane holds fewer than 2^30 texels. */
CLONES void scatter_march(const float *planes, int64_t plane_len, int64_t nbp, const double *xs, int64_t nx,
                          double lim_a, double lim_b, const double *coef, const float *ns_all, const int64_t *start,
                          const int64_t *end, int64_t n, int64_t first, int64_t block, float *acc_all, float *tr_all,
                          int64_t *act, double *dwork, float *fwork, int32_t *qwork)
{
    const unsigned csr = nph_flush_denormals();
    const double *c[4] = {coef, coef + n, coef + 2 * n, coef + 3 * n};
    struct flight f = {dwork, dwork + n, dwork + 2 * n, dwork + 3 * n, fwork, fwork + n, fwork + 2 * n, fwork + 3 * n,
                       fwork + 4 * n, qwork};
    double *fd[4] = {f.a0, f.a1, f.b0, f.b1};
    for (int64_t r = 0; r < n; r++) {
        acc_all[r] = 0.0f;
        tr_all[r] = 1.0f;
    }
    int64_t k = 0, joined = 0;
    for (int64_t p0 = first; p0 < nx; p0 += block) {
        int64_t m = 0; /* the rays past their last sample leave, with their sums */
        for (int64_t j = 0; j < k; j++) {
            const int64_t r = act[j];
            if (end[r] < p0) {
                acc_all[r] = f.acc[j];
                tr_all[r] = f.tr[j];
                continue;
            }
            act[m] = r;
            for (int i = 0; i < 4; i++)
                fd[i][m] = fd[i][j];
            f.ns[m] = f.ns[j];
            f.acc[m] = f.acc[j];
            f.tr[m] = f.tr[j];
            m++;
        }
        for (k = m; joined < n && start[joined] < p0 + block; joined++, k++) { /* those starting here join */
            act[k] = joined;
            for (int i = 0; i < 4; i++)
                fd[i][k] = c[i][joined];
            f.ns[k] = ns_all[joined];
            f.acc[k] = acc_all[joined];
            f.tr[k] = tr_all[joined];
        }
        const int64_t p1 = p0 + block < nx ? p0 + block : nx;
        for (int64_t s = p0; s < p1 && k > 0; s++)
            march_sample(planes + 2 * s * plane_len, nbp, xs[s], lim_a, lim_b, &f, k);
    }
    for (int64_t j = 0; j < k; j++) {
        acc_all[act[j]] = f.acc[j];
        tr_all[act[j]] = f.tr[j];
    }
    nph_restore_denormals(csr);
}
