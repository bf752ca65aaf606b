/* float32 exp and expm1 for the scattering kernels (native/src/scatter_*.c), as plain inline C the
 * compiler vectorizes inside a loop (libm's expf is one call per value, and glibc's newer symbol
 * versions would raise the wheel's manylinux level).
 *
 * Cody-Waite reduction x = k ln2 + r, |r| <= ln2 / 2, a degree 7 Taylor polynomial (truncation below
 * 6e-9 relative), scaled by 2^k built in the exponent bits; below NPH_EXPF_MIN the result is 0 (the
 * true value is under 1.7e-38, next to the denormals), above NPH_EXPF_MAX it is exp(NPH_EXPF_MAX).  expm1 takes
 * its Taylor series below |x| = 1/2 (no cancellation) and exp(x) - 1 above.  Measured against
 * NumPy's float32 exp / expm1 in tests/core/light/test_scatter_native.py.
 */

#ifndef NEPHELE_SCATTER_MATH_H
#define NEPHELE_SCATTER_MATH_H

/* GCC keeps floating-point comparisons from raising exceptions early (-ftrapping-math, its default),
 * so it turns no select of a comparison into vector code: every loop with one stays scalar (GCC 12).
 * These kernels read no exception flags.  (Clang ignores them by default.)  No fp-contract=fast:
 * fused multiply-adds in the x86-64-v3 clone made Linux on FMA processors differ from Windows,
 * macOS and older processors (tests/native/test_wine.py; native/build.py's -ffp-contract=off). */
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize("no-trapping-math")
#endif

#include <stdint.h>
#include <string.h>

#include "nph_inline.h"
#if defined(__x86_64__) || defined(_M_X64) || defined(__i386__)
#include <xmmintrin.h>
#define NPH_X86 1
#endif

#define NPH_EXPF_MIN (-87.0f)
#define NPH_EXPF_MAX 88.0f
#define NPH_TINY 1.17549435e-38f /* the smallest normal float32 (np.finfo(np.float32).tiny) */

/* Denormal numbers cost x86 a microcode assist each (~100 cycles): an empty voxel's tau = 0 gives
 * the series 1e-38-sized terms, and a kernel ran 5x slower on a cloud with holes.  The kernels
 * flush them to zero while they run (the thread's own MXCSR, restored after); values below 1.2e-38
 * carry no light worth keeping.  Other processors take them at full speed. */
static inline unsigned nph_flush_denormals(void)
{
#ifdef NPH_X86
    unsigned csr = _mm_getcsr();
    _mm_setcsr(csr | 0x8040); /* flush to zero, denormals are zero */
    return csr;
#else
    return 0;
#endif
}

static inline void nph_restore_denormals(unsigned csr)
{
#ifdef NPH_X86
    _mm_setcsr(csr);
#else
    (void)csr;
#endif
}

NPH_INLINE float nph_minf(float a, float b) { return a < b ? a : b; }
NPH_INLINE float nph_maxf(float a, float b) { return a > b ? a : b; }
NPH_INLINE float nph_absf(float a) { return a < 0.0f ? -a : a; }
NPH_INLINE float nph_clampf(float x, float lo, float hi) { return nph_minf(nph_maxf(x, lo), hi); }

/* x (clamped to [NPH_EXPF_MIN, NPH_EXPF_MAX]) = k ln2 + r with |r| <= ln2 / 2: returns r, 2^k in *scale */
NPH_INLINE float nph_exp_reduce(float x, float *scale)
{
    float xc = nph_clampf(x, NPH_EXPF_MIN, NPH_EXPF_MAX);
    /* k = round(x / ln2) by the 1.5 * 2^23 trick (exact for |x / ln2| < 2^22) */
    float kf = xc * 1.44269504f + 12582912.0f;
    int32_t ki;
    memcpy(&ki, &kf, sizeof ki);
    kf -= 12582912.0f;
    int32_t e = ((ki - 0x4B400000) + 127) << 23; /* ki's low bits hold k (offset by the trick's exponent) */
    memcpy(scale, &e, sizeof *scale);
    return (xc - kf * 0.693145752f) - kf * 1.42860677e-6f; /* ln2 = hi + lo, hi with 12 zero low bits */
}

/* expm1(r) for |r| <= ln2 / 2: its degree 7 Taylor polynomial, by Estrin's scheme (pairs of terms
 * summed side by side, joined by powers of r^2): a chain of 6 operations, not Horner's 13.  The row
 * kernels wait on such chains (one iteration of the profile rows is more than a Zen core's
 * out-of-order window holds): the Fig. 6 cloud's 64x64x48 sweeps 1.79-1.82 -> 1.65-1.72 s (AMD EPYC,
 * three solves each, alternated). */
NPH_INLINE float nph_expm1_reduced(float r)
{
    float r2 = r * r;
    float a = 1.0f + r * 0.5f, b = 1.0f / 6 + r * (1.0f / 24), c = 1.0f / 120 + r * (1.0f / 720);
    return r * ((a + r2 * b) + (r2 * r2) * (c + r2 * (1.0f / 5040)));
}

NPH_INLINE float nph_expf(float x)
{
    float scale, r = nph_exp_reduce(x, &scale);
    float y = (1.0f + nph_expm1_reduced(r)) * scale; /* computed on every path: GCC (trapping math)
                                                         vectorizes only selects of values */
    return x < NPH_EXPF_MIN ? 0.0f : y;
}

/* expm1(x), and exp(x) in *ex, from one reduction: exp(x) = 2^k (1 + q) and expm1(x) = 2^k q +
 * (2^k - 1) with q = expm1(r), exact for k = 0 (|x| < ln2 / 2) and within two float32 ulps beyond
 * (|x| to 1/2: 2 q + 1 or q / 2 - 1/2, no cancellation).  Where a caller needs both this is one
 * polynomial, not nph_expf's and expm1's own series. */
NPH_INLINE float nph_exp_expm1f(float x, float *ex)
{
    float scale, r = nph_exp_reduce(x, &scale);
    float y = scale * nph_expm1_reduced(r);
    *ex = x < NPH_EXPF_MIN ? 0.0f : y + scale;
    return x < NPH_EXPF_MIN ? -1.0f : y + (scale - 1.0f);
}

NPH_INLINE float nph_expm1f(float x)
{
    float s = x * (1.0f + x * (0.5f + x * (1.0f / 6 + x * (1.0f / 24 + x * (1.0f / 120 + x * (1.0f / 720
              + x * (1.0f / 5040 + x * (1.0f / 40320))))))));
    float e = nph_expf(x) - 1.0f;
    return nph_absf(x) < 0.5f ? s : e;
}

/* (1 - exp(-x)) / x for x >= 0 (1 at 0): scatter's _phi */
NPH_INLINE float nph_phif(float x)
{
    float n = -nph_maxf(x, NPH_TINY);
    return nph_expm1f(n) / n;
}

#endif
