/* Vertex projection of the blobby mesher (nephele.core.muscle.blobby._project).
 *
 * Each vertex slides along its grid edge onto f = level, f the sum of its block's fine Gaussian
 * list, by the NumPy twin's rules (tolerance, settle rule, bracket with bisection, edge margin, step
 * limit) in double precision.  Vertices come sorted by block: a block's list is gathered once, and
 * four of its vertices are evaluated at a time, one per vector lane (fastexp.h), each Gaussian's
 * terms independent of the last (a loop over Gaussians in lanes would wait on the exp's latency).
 * A lane whose vertex is done takes the block's next one.  A vertex's sums run over its block's list
 * in order whatever lane it has: the same bits in any chunk, and a Gaussian adding exactly 0 changes
 * no bit.
 */

#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "fastexp.h"

/* An AVX2 clone beside the baseline one, chosen at load time: GCC on x86-64 ELF (ifunc).  Zig's
 * clang for Windows and macOS has no runtime for the choice (__cpu_model): baseline code there. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define CLONES __attribute__((target_clones("avx2", "default")))
#else
#define CLONES
#endif

enum { CX, CY, CZ, AXX, AYY, AZZ, AXY, AXZ, AYZ, LNW, NCOL };

struct rules {
    double level, tol, settle, margin;
    int64_t steps;
};

/* One vertex on its edge: the lower node's position, the edge's axis and length, the edge
 * parameter t in the bracket [lo, hi], Newton steps taken. */
struct lane {
    int64_t v, steps;
    double base[3], st, t, lo, hi, cv;
    int ax, above;
};

/* The block's Gaussians gathered: NCOL values per Gaussian, then their input indices. */
static void gather(double *col, int64_t *src_out, int64_t lo, int64_t hi, const int64_t *fine_g, const double *gc,
                   const double *ga, const double *lnw, const int64_t *src)
{
    for (int64_t j = lo; j < hi; j++, col += NCOL) {
        int64_t g = fine_g[j];
        for (int a = 0; a < 3; a++)
            col[CX + a] = gc[3 * g + a];
        for (int a = 0; a < 6; a++)
            col[AXX + a] = ga[6 * g + a];
        col[LNW] = lnw[g];
        src_out[j - lo] = src[g];
    }
}

/* f, its gradient and the list position of the largest term (the first of equals; 0 when every
 * term is 0, as NumPy's argmax) at four points, one per lane. */
static inline __attribute__((always_inline)) void field4(const double *col, int64_t ng, nph_v4d px, nph_v4d py,
                                                         nph_v4d pz, double *f, double *gx, double *gy, double *gz,
                                                         int64_t *best)
{
    nph_v4d sf = nph_splat4(0.0), sx = sf, sy = sf, sz = sf, top = sf;
    nph_v4l at = {0, 0, 0, 0};
    for (int64_t g = 0; g < ng; g++, col += NCOL) {
        nph_v4d dx = px - nph_splat4(col[CX]), dy = py - nph_splat4(col[CY]), dz = pz - nph_splat4(col[CZ]);
        nph_v4d axy = nph_splat4(col[AXY]), axz = nph_splat4(col[AXZ]), ayz = nph_splat4(col[AYZ]);
        nph_v4d ux = nph_splat4(col[AXX]) * dx + axy * dy + axz * dz; /* A d */
        nph_v4d uy = axy * dx + nph_splat4(col[AYY]) * dy + ayz * dz;
        nph_v4d uz = axz * dx + ayz * dy + nph_splat4(col[AZZ]) * dz;
        nph_v4d e = nph_exp4(nph_splat4(col[LNW]) - 0.5 * (dx * ux + dy * uy + dz * uz));
        sf += e;
        sx -= e * ux;
        sy -= e * uy;
        sz -= e * uz;
        nph_v4l more = e > top;
        top = nph_select4(more, e, top);
        at = (at & ~more) | ((nph_v4l){g, g, g, g} & more);
    }
    for (int l = 0; l < 4; l++) {
        f[l] = sf[l];
        gx[l] = sx[l];
        gy[l] = sy[l];
        gz[l] = sz[l];
        best[l] = at[l];
    }
}

/* One Newton (or bisection) step of a lane from f and grad at its t.  Returns whether the vertex
 * is done, with its final edge parameter in *final. */
static inline int advance(struct lane *L, const struct rules *r, double f, const double *grad, double *final)
{
    double t = L->t;
    *final = t;
    if (L->steps == r->steps)
        return 1;
    L->steps++;
    double diff = f - r->level;
    double gn = sqrt(grad[0] * grad[0] + grad[1] * grad[1] + grad[2] * grad[2]);
    double slack = r->tol * (gn > 1e-300 ? gn : 1e-300);
    if (!(fabs(diff) >= slack)) /* (NaN: done) */
        return 1;
    if ((diff > 0) == L->above) /* still on the lower node's side */
        L->lo = t;
    else
        L->hi = t;
    double nt = t - diff / (grad[L->ax] * L->st);
    int good = nt > L->lo && nt < L->hi; /* false for NaN */
    nt = good ? nt : 0.5 * (L->lo + L->hi);
    nt = nt > r->margin ? nt : r->margin;
    nt = nt < 1 - r->margin ? nt : 1 - r->margin;
    double dt = nt - t;
    /* A short step ends the vertex: its second-order error is below the tolerance, and its normal
     * (from where it starts) off by about the step over the surface's radius. */
    if (good && 2 * L->cv * dt * dt < slack && fabs(dt) * L->st < r->settle * r->tol) {
        *final = nt;
        return 1;
    }
    if (nt == t)
        return 1;
    L->t = nt;
    return 0;
}

/* The per-vertex inputs and the grid. */
struct verts {
    const int8_t *axis;
    const uint8_t *node, *above;
    const double *t, *h, *box;
    const float *curv;
    const int64_t *node_n;
    int64_t block;
};

/* Lane L takes vertex v of the block with coordinates qb (node node_n[a] of a periodic axis lies at
 * exactly box[a]: the grid's coords). */
static inline void start(struct lane *L, int64_t v, const int64_t *qb, const struct verts *in)
{
    L->v = v;
    for (int a = 0; a < 3; a++) {
        int64_t k = qb[a] * in->block + in->node[3 * v + a];
        L->base[a] = k == in->node_n[a] ? in->box[a] : (double)k * in->h[a];
    }
    L->ax = in->axis[v];
    L->st = in->h[L->ax];
    L->t = in->t[v];
    L->lo = 0.0;
    L->hi = 1.0;
    L->cv = fabs((double)in->curv[v]);
    L->above = in->above[v] != 0;
    L->steps = 0;
}

/* Project vertices vid[0..n) (sorted by block): see _project for the vertex arrays and outputs, and
 * _project_c for the rest.  Returns 0, or -1 when out of memory. */
CLONES int blobby_project(
    int64_t n, const int64_t *vid, const int32_t *blk, const int8_t *axis, const uint8_t *node, const double *t,
    const float *curv, const uint8_t *above, const int64_t *q, const int64_t *fine_start, const int64_t *fine_g,
    const double *gc, const double *ga, const double *lnw, const int64_t *src, int64_t gmax, const double *h,
    const double *box, const int64_t *node_n, int64_t block, double level, double tol, double settle, double margin,
    int64_t steps, float *pos, float *normal, uint8_t *flat, int32_t *arg)
{
    double *col = malloc((size_t)(gmax > 0 ? gmax : 1) * NCOL * sizeof(double));
    int64_t *gsrc = malloc((size_t)(gmax > 0 ? gmax : 1) * sizeof(int64_t));
    if (!col || !gsrc) {
        free(col);
        free(gsrc);
        return -1;
    }
    const struct rules r = {level, tol, settle, margin, steps};
    const struct verts in = {axis, node, above, t, h, box, curv, node_n, block};
    for (int64_t i0 = 0, i1; i0 < n; i0 = i1) {
        int64_t b = blk[vid[i0]], next = i0;
        for (i1 = i0 + 1; i1 < n && blk[vid[i1]] == b; i1++)
            ;
        gather(col, gsrc, fine_start[b], fine_start[b + 1], fine_g, gc, ga, lnw, src);
        int64_t ng = fine_start[b + 1] - fine_start[b];
        struct lane L[4];
        int on[4] = {0, 0, 0, 0};
        for (;;) {
            nph_v4d px = nph_splat4(0.0), py = px, pz = px; /* (idle lanes: any point) */
            int any = 0;
            for (int l = 0; l < 4; l++) {
                if (!on[l] && next < i1) { /* an idle lane takes the block's next vertex */
                    start(&L[l], vid[next++], q + 3 * b, &in);
                    on[l] = 1;
                }
                if (!on[l])
                    continue;
                any = 1;
                double p[3] = {L[l].base[0], L[l].base[1], L[l].base[2]};
                p[L[l].ax] += L[l].t * L[l].st;
                px[l] = p[0];
                py[l] = p[1];
                pz[l] = p[2];
            }
            if (!any)
                break;
            double f[4], gx[4], gy[4], gz[4];
            int64_t best[4];
            field4(col, ng, px, py, pz, f, gx, gy, gz, best);
            for (int l = 0; l < 4; l++) {
                double grad[3] = {gx[l], gy[l], gz[l]}, final;
                if (!on[l] || !advance(&L[l], &r, f[l], grad, &final))
                    continue;
                int64_t v = L[l].v;
                double gn = sqrt(grad[0] * grad[0] + grad[1] * grad[1] + grad[2] * grad[2]), d = gn > 0 ? gn : 1.0;
                for (int a = 0; a < 3; a++) {
                    pos[3 * v + a] = (float)(L[l].base[a] + (a == L[l].ax ? final * L[l].st : 0.0));
                    normal[3 * v + a] = (float)(-grad[a] / d);
                }
                flat[v] = gn <= 0;
                arg[v] = (int32_t)gsrc[best[l]];
                on[l] = 0;
            }
        }
    }
    free(col);
    free(gsrc);
    return 0;
}

/* y = exp(x) by fastexp.h, for its test against numpy.exp. */
void blobby_fastexp(int64_t n, const double *x, double *y)
{
    for (int64_t i = 0; i < n; i += 4) {
        nph_v4d v = nph_splat4(0.0);
        for (int k = 0; k < 4 && i + k < n; k++)
            v[k] = x[i + k];
        v = nph_exp4(v);
        for (int k = 0; k < 4 && i + k < n; k++)
            y[i + k] = v[k];
    }
}
