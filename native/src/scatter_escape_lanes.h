/* The profile rows' escapes (scatter_sweep.c's row_escapes) on NPH_LANES vectors of 8 voxels at
 * once, each statement written for every vector before the next: scatter_escape.h's and
 * scatter_math.h's closed forms, operation for operation (the same values to the bit), in GCC/Clang
 * vector extensions.
 *
 * Why: one voxel's escapes are a chain of about 57 dependent operations (three exponentials, four
 * divisions), and one 8-voxel iteration of the compiled loop is about 260 micro-operations on a Zen 1
 * core (which splits 256-bit operations), more than its 192-entry reorder buffer holds: iterations
 * hardly overlap and the loop waits on its chain.  Three chains side by side, statement by statement,
 * keep the core busy while each waits (GCC does not interleave two voxels' bodies itself: it leaves
 * such a loop scalar).  Measured on the AMD EPYC (one row of 2208 voxels, first moments): 11.2 ->
 * 7.8 ns a voxel, the same outputs to the bit.  The AVX-512 clone keeps the plain loop (16-wide
 * vectors, 32 registers and a larger window; lanes there not measured: no such machine at hand).
 */

#ifndef NEPHELE_SCATTER_ESCAPE_LANES_H
#define NEPHELE_SCATTER_ESCAPE_LANES_H

#include <stdint.h>

#include "scatter_escape.h"

#define NPH_LANES 3 /* vectors side by side (2: 9.0 ns a voxel, 4: no faster than 3) */
#define NPH_VW 8    /* floats a vector */

typedef float nph_v8 __attribute__((vector_size(NPH_VW * sizeof(float)), aligned(sizeof(float))));
typedef int32_t nph_v8i __attribute__((vector_size(NPH_VW * sizeof(float)), aligned(sizeof(float))));

#define LANES for (int u = 0; u < NPH_LANES; u++)

/* m ? a : b per element (m: a comparison's all-ones or zero) */
NPH_INLINE nph_v8 nph_vsel(nph_v8i m, nph_v8 a, nph_v8 b) { return (nph_v8)((m & (nph_v8i)a) | (~m & (nph_v8i)b)); }
NPH_INLINE nph_v8 nph_vsplat(float x) { return (nph_v8){x, x, x, x, x, x, x, x}; }
/* nph_minf, nph_maxf, nph_absf, nph_clampf: the same comparisons */
NPH_INLINE nph_v8 nph_vmin(nph_v8 a, nph_v8 b) { return nph_vsel(a < b, a, b); }
NPH_INLINE nph_v8 nph_vmax(nph_v8 a, nph_v8 b) { return nph_vsel(a > b, a, b); }
NPH_INLINE nph_v8 nph_vabs(nph_v8 a) { return nph_vsel(a < 0.0f, -a, a); }
NPH_INLINE nph_v8 nph_vclamp(nph_v8 x, float lo, float hi) { return nph_vmin(nph_vmax(x, nph_vsplat(lo)), nph_vsplat(hi)); }

/* nph_exp_reduce and nph_expm1_reduced: q = expm1(r) and the scale 2^k of each x */
NPH_INLINE void nph_vexp_parts(const nph_v8 *x, nph_v8 *q, nph_v8 *scale)
{
    nph_v8 xc[NPH_LANES], kf[NPH_LANES], r[NPH_LANES], r2[NPH_LANES], a[NPH_LANES], b[NPH_LANES], c[NPH_LANES];
    LANES xc[u] = nph_vclamp(x[u], NPH_EXPF_MIN, NPH_EXPF_MAX);
    LANES kf[u] = xc[u] * 1.44269504f + 12582912.0f;
    LANES scale[u] = (nph_v8)((((nph_v8i)kf[u] - 0x4B400000) + 127) << 23);
    LANES kf[u] = kf[u] - 12582912.0f;
    LANES r[u] = (xc[u] - kf[u] * 0.693145752f) - kf[u] * 1.42860677e-6f;
    LANES r2[u] = r[u] * r[u];
    LANES a[u] = 1.0f + r[u] * 0.5f;
    LANES b[u] = 1.0f / 6 + r[u] * (1.0f / 24);
    LANES c[u] = 1.0f / 120 + r[u] * (1.0f / 720);
    LANES q[u] = r[u] * ((a[u] + r2[u] * b[u]) + (r2[u] * r2[u]) * (c[u] + r2[u] * (1.0f / 5040)));
}

/* nph_expf */
NPH_INLINE void nph_vexpf(const nph_v8 *x, nph_v8 *out)
{
    nph_v8 q[NPH_LANES], s[NPH_LANES];
    nph_vexp_parts(x, q, s);
    LANES out[u] = nph_vsel(x[u] < NPH_EXPF_MIN, nph_vsplat(0.0f), (1.0f + q[u]) * s[u]);
}

/* nph_exp_expm1f: expm1 in m1, exp in ex */
NPH_INLINE void nph_vexp_expm1f(const nph_v8 *x, nph_v8 *m1, nph_v8 *ex)
{
    nph_v8 q[NPH_LANES], s[NPH_LANES], y[NPH_LANES];
    nph_vexp_parts(x, q, s);
    LANES y[u] = s[u] * q[u];
    LANES ex[u] = nph_vsel(x[u] < NPH_EXPF_MIN, nph_vsplat(0.0f), y[u] + s[u]);
    LANES m1[u] = nph_vsel(x[u] < NPH_EXPF_MIN, nph_vsplat(-1.0f), y[u] + (s[u] - 1.0f));
}

/* escape_centroid */
NPH_INLINE void nph_vescape_centroid(const nph_v8 *tau, const nph_v8 *beta, const nph_v8 *t, nph_v8 *esc, nph_v8 *vs)
{
    nph_v8 a[NPH_LANES], na[NPH_LANES], nd[NPH_LANES], ma[NPH_LANES], ea[NPH_LANES], ed[NPH_LANES], unused[NPH_LANES];
    LANES a[u] = nph_vabs(beta[u]);
    LANES na[u] = -nph_vmax(a[u], nph_vsplat(1e-18f));
    nph_vexp_expm1f(na, ma, ea);
    LANES nd[u] = -nph_vmax(nph_vabs(beta[u] - tau[u]), nph_vsplat(1e-18f));
    nph_vexp_expm1f(nd, ed, unused);
    nph_v8 e[NPH_LANES], k2[NPH_LANES], series[NPH_LANES], big[NPH_LANES];
    LANES e[u] = nph_vsel(beta[u] <= 0.0f, nph_vsplat(1.0f), nph_vsel(beta[u] >= tau[u], t[u], ea[u]));
    LANES e[u] = e[u] * (ed[u] * na[u]) / (nd[u] * ma[u]);
    LANES k2[u] = beta[u] * beta[u];
    LANES series[u] = beta[u] * (-1.0f / 12 + k2[u] * (1.0f / 720 - k2[u] * (1.0f / 30240)));
    LANES big[u] = (na[u] - ma[u]) / (ma[u] * na[u]) + 0.5f;
    LANES big[u] = nph_vsel(beta[u] > 0.0f, big[u], -big[u]);
    LANES vs[u] = nph_vsel(a[u] < 0.5f, series[u], big[u]) + 0.5f;
    LANES esc[u] = nph_vclamp(e[u], 0.0f, 1.0f);
}

/* p2_escape */
NPH_INLINE void nph_vp2_escape(const nph_v8 *tau, const nph_v8 *t, nph_v8 *out)
{
    nph_v8 a[NPH_LANES], e[NPH_LANES], a2[NPH_LANES], big[NPH_LANES], ts[NPH_LANES], s[NPH_LANES];
    LANES a[u] = nph_vclamp(tau[u], 1.0f, 1e12f);
    LANES e[u] = nph_vmin(t[u], nph_vsplat(0.36787944f));
    LANES a2[u] = a[u] * a[u];
    LANES big[u] = (a2[u] - 6.0f * a[u] + 12.0f - e[u] * (a2[u] + 6.0f * a[u] + 12.0f)) / (a2[u] * a[u]);
    LANES ts[u] = nph_vmin(tau[u], nph_vsplat(1.0f));
    LANES s[u] = nph_vsplat(P2S[8]);
    for (int n = 7; n >= 0; n--)
        LANES s[u] = s[u] * ts[u] + P2S[n];
    LANES s[u] = s[u] * ts[u] * ts[u];
    LANES out[u] = nph_vsel(tau[u] < 1.0f, s[u], big[u]);
}

/* Voxels [i, i + NPH_LANES NPH_VW) of row_escapes: the same arguments, the same outputs. */
NPH_INLINE void nph_vrow_escapes(int64_t i, float ell, float c0, float c1, float c2, const float *restrict sg,
                                 const float *restrict k0, const float *restrict k1, const float *restrict k2,
                                 const float *restrict qa, const float *restrict vr, float *restrict ce,
                                 float *restrict cs, float *restrict ck, float *restrict ct, const int QA,
                                 const int MOM, const int M2)
{
#define LOAD(p) (*(const nph_v8 *)((p) + i + u * NPH_VW))
#define STORE(p, v) (*(nph_v8 *)((p) + i + u * NPH_VW) = (v))
    nph_v8 tau[NPH_LANES], mtau[NPH_LANES], t[NPH_LANES], beta[NPH_LANES], esc[NPH_LANES], vs[NPH_LANES];
    LANES tau[u] = LOAD(sg) * ell;
    LANES mtau[u] = -tau[u];
    nph_vexpf(mtau, t);
    LANES beta[u] = c0 * LOAD(k0) + c1 * LOAD(k1) + c2 * LOAD(k2);
    nph_vescape_centroid(tau, beta, t, esc, vs);
    if (QA) {
        nph_v8 p2[NPH_LANES];
        nph_vp2_escape(tau, t, p2);
        LANES esc[u] = nph_vclamp(esc[u] + LOAD(qa) * p2[u], 0.0f, 1.0f);
    }
    nph_v8 shift[NPH_LANES], kept2[NPH_LANES];
    LANES shift[u] = kept2[u] = nph_vsplat(0.0f);
    if (MOM) {
        nph_v8 kept[NPH_LANES], tm[NPH_LANES];
        LANES kept[u] = nph_vmax(1.0f - esc[u], nph_vsplat(1e-30f));
        LANES tm[u] = nph_vmax(tau[u], nph_vsplat(1e-2f));
        LANES shift[u] = ((vs[u] - esc[u]) * tm[u] + kept[u]) / (kept[u] * tm[u]) - vs[u];
        LANES shift[u] = nph_vclamp(shift[u], -1.0f, 1.0f);
        LANES shift[u] = nph_vsel(tau[u] < 1e-2f, nph_vsplat(1.0f / 6), shift[u]);
        if (M2) {
            nph_v8 ti[NPH_LANES], m2s[NPH_LANES];
            LANES ti[u] = 1.0f / nph_vmax(tau[u], nph_vsplat(0.1f));
            LANES m2s[u] = LOAD(vr) + (vs[u] - 0.5f) * (vs[u] - 0.5f);
            LANES kept2[u] = m2s[u] + (vs[u] + vs[u] - 1.0f - esc[u]) * ti[u] + 2.0f * kept[u] * ti[u] * ti[u]
                             - 0.25f * esc[u];
            LANES kept2[u] = nph_vsel(tau[u] < 0.1f, kept[u] * m2s[u], kept2[u]);
            LANES kept2[u] = nph_vmin(nph_vmax(kept2[u], nph_vsplat(0.0f)), 0.25f * kept[u]);
        }
    }
    LANES STORE(ce, esc[u]);
    LANES STORE(cs, shift[u]);
    LANES STORE(ck, kept2[u]);
    LANES STORE(ct, t[u]);
#undef LOAD
#undef STORE
}

#undef LANES

#endif
