/* exp in double precision, four lanes at a time (GCC/Clang vector extensions: whole registers in
 * a target clone with AVX2, two SSE2 registers elsewhere), for kernels whose exp dominates and whose
 * sums must vectorize (libm's exp is one call per value).
 *
 * Cody-Waite reduction x = k ln2 + r, |r| <= ln2 / 2 (ln2's high part has 21 zero bits: k ln2_hi is
 * exact), Taylor polynomial of degree 12 for e^r (truncation below 2.5e-16), scaled by 2^k built in the
 * exponent bits.  Max relative error against numpy.exp over [-708, 709]: 4.5e-16 (2 ulp) (see
 * tests/core/muscle/test_blobby_native_project.py).  Below NPH_EXP_MIN the result is 0 (the true
 * value is below 3.3e-308, where the scaling would leave the normal range), -inf included; above
 * NPH_EXP_MAX it is exp(NPH_EXP_MAX); NaN stays NaN.  The 32-byte vectors pass only between static
 * inline functions, never across an ABI boundary (build.py's -Wno-psabi silences GCC's notice).
 */

#ifndef NEPHELE_FASTEXP_H
#define NEPHELE_FASTEXP_H

#include <stdint.h>

#include "nph_inline.h"

typedef double nph_v4d __attribute__((vector_size(32)));
typedef int64_t nph_v4l __attribute__((vector_size(32)));

#define NPH_EXP_MIN (-708.0)
#define NPH_EXP_MAX 709.0

NPH_INLINE nph_v4d nph_splat4(double x)
{
    return (nph_v4d){x, x, x, x};
}

/* m ? a : b per lane (m: all bits set or none, as comparisons give). */
NPH_INLINE nph_v4d nph_select4(nph_v4l m, nph_v4d a, nph_v4d b)
{
    return (nph_v4d)(((nph_v4l)a & m) | ((nph_v4l)b & ~m));
}

NPH_INLINE nph_v4d nph_exp4(nph_v4d x)
{
    const nph_v4d shift = nph_splat4(0x1.8p52); /* adding it rounds to an integer, kept in the low bits */
    nph_v4l under = x < nph_splat4(NPH_EXP_MIN);
    nph_v4d xc = nph_select4(under, nph_splat4(NPH_EXP_MIN), x);
    xc = nph_select4(xc > nph_splat4(NPH_EXP_MAX), nph_splat4(NPH_EXP_MAX), xc);
    nph_v4d kd = xc * nph_splat4(0x1.71547652b82fep0) + shift; /* x / ln2 */
    nph_v4l k = (nph_v4l)kd;                                  /* k in the low mantissa bits */
    kd -= shift;
    nph_v4d r = (xc - kd * nph_splat4(0x1.62e42fee00000p-1)) - kd * nph_splat4(0x1.a39ef35793c76p-33);
    /* Estrin's scheme: a dependency chain of 4 multiply-adds instead of Horner's 12 (the latency
     * bounds a short loop) */
    nph_v4d r2 = r * r, r4 = r2 * r2;
    nph_v4d p01 = nph_splat4(1.0) + r, p23 = nph_splat4(1.0 / 2) + nph_splat4(1.0 / 6) * r;
    nph_v4d p45 = nph_splat4(1.0 / 24) + nph_splat4(1.0 / 120) * r;
    nph_v4d p67 = nph_splat4(1.0 / 720) + nph_splat4(1.0 / 5040) * r;
    nph_v4d p89 = nph_splat4(1.0 / 40320) + nph_splat4(1.0 / 362880) * r;
    nph_v4d p1011 = nph_splat4(1.0 / 3628800) + nph_splat4(1.0 / 39916800) * r;
    nph_v4d q0 = p01 + r2 * p23, q1 = p45 + r2 * p67, q2 = p89 + r2 * (p1011 + r2 * nph_splat4(1.0 / 479001600));
    nph_v4d p = q0 + r4 * (q1 + r4 * q2);
    /* 2^k: k's bits shifted into the exponent field (the rounding constant's bits fall off the top). */
    nph_v4d scale = (nph_v4d)((k << 52) + ((int64_t)1023 << 52));
    return nph_select4(under, nph_splat4(0.0), p * scale);
}

NPH_INLINE double nph_exp(double x)
{
    return nph_exp4(nph_splat4(x))[0];
}

#endif
