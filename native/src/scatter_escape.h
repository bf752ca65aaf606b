/* The closed forms of the scattering sweeps in float32, the compiled twins of
 * nephele.core.light._escape's, inlined into scatter_sweep.c's row kernels (a call would leave
 * their loops scalar).  The sweeps using them are compared with their NumPy twin in
 * tests/core/light/test_scatter_native.py. */

#ifndef NEPHELE_SCATTER_ESCAPE_H
#define NEPHELE_SCATTER_ESCAPE_H

#include "scatter_math.h"

/* escape fraction (clipped to [0, 1]) and centroid along the path of a source exp(-beta v) over
 * optical depth tau (t = exp(-tau)): _escape_centroid.  exp(min(beta, 0) - min(tau, beta)) is 1,
 * t or exp(-|beta|), which expm1(-|beta|) needs anyway: two exponentials per call, not four, each
 * with its expm1 from the same polynomial (nph_exp_expm1f: the 64x64x48 solve's sweeps 5 % faster
 * than with expm1's own series).  Two divisions where the twin has four (vector division is the
 * slowest operation here); the floors keep the products normal, and phi(x) is 1 to float32 below
 * them. */
NPH_INLINE void escape_centroid(float tau, float beta, float t, float *esc, float *vs)
{
    float a = nph_absf(beta);
    float na = -nph_maxf(a, 1e-18f);
    float ea, unused;
    float ma = nph_exp_expm1f(na, &ea);
    float nd = -nph_maxf(nph_absf(beta - tau), 1e-18f);
    float ed = nph_exp_expm1f(nd, &unused);
    float big_e = beta >= tau ? t : ea;
    float ee = beta <= 0.0f ? 1.0f : big_e;
    float e = ee * (ed * na) / (nd * ma);
    float k2 = beta * beta;
    float series = beta * (-1.0f / 12 + k2 * (1.0f / 720 - k2 * (1.0f / 30240)));
    float big = (na - ma) / (ma * na) + 0.5f; /* 1 / ma - 1 / na + 1/2 = _offset(|beta|) <= 0, odd in beta */
    big = beta > 0.0f ? big : -big;
    *vs = (a < 0.5f ? series : big) + 0.5f;
    *esc = nph_clampf(e, 0.0f, 1.0f);
}

/* _offset(tau) for tau >= 0, t = exp(-tau): 1 / (t - 1) + 1 / tau + 1/2 from tau = 1/2 on */
NPH_INLINE float offset_pos(float tau, float t)
{
    float k2 = tau * tau;
    float series = tau * (-1.0f / 12 + k2 * (1.0f / 720 - k2 * (1.0f / 30240)));
    float m = nph_maxf(tau, 0.5f);
    float big = (m + (t - 1.0f)) / ((t - 1.0f) * m) + 0.5f;
    return tau < 0.5f ? series : big;
}

/* _variance(tau, t) */
NPH_INLINE float variance(float tau, float t)
{
    float e = nph_minf(t, 0.60653066f);
    float ac2 = nph_maxf(tau, 0.5f) * nph_maxf(tau, 0.5f), f = (1.0f - e) * (1.0f - e);
    float big = (f - e * ac2) / (ac2 * f); /* 1 / ac^2 - e / (1 - e)^2 */
    float k2 = tau * tau;
    float series = 1.0f / 12 - k2 * (1.0f / 240 - k2 * (1.0f / 6048));
    return tau < 0.5f ? series : big;
}

/* _p2_escape(tau, t): coefficients (-1)^n c_n / n! of its series, n = 2..10 (_P2_SERIES, float32) */
static const float P2S[9] = {
    0.01666666753590107f, -0.008333333767950535f, 0.0023809524718672037f, -0.0004960317746736109f,
    8.26719551696442e-05f, -1.1574074051168282e-05f, 1.4029180874786107e-06f, -1.5031264410936274e-07f,
    1.4453139129955161e-08f,
};

NPH_INLINE float p2_escape(float tau, float t)
{
    float a = nph_clampf(tau, 1.0f, 1e12f);
    float e = nph_minf(t, 0.36787944f);
    float a2 = a * a;
    float big = (a2 - 6.0f * a + 12.0f - e * (a2 + 6.0f * a + 12.0f)) / (a2 * a);
    float ts = nph_minf(tau, 1.0f);
    float s = P2S[8];
    for (int n = 7; n >= 0; n--)
        s = s * ts + P2S[n];
    s = s * ts * ts;
    return tau < 1.0f ? s : big;
}

#endif
