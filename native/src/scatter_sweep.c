/* The scattering solve's sweeps: the compiled twin of nephele.core.light._sweep._sweep_block.
 *
 * One call sweeps bins [bin_lo, bin_hi) of one group (beams sharing the sweep axis and its sign),
 * each bin with its ns sub-beams, through all layers; Python calls it per bin from its threads
 * (the bins never share an output).  Per layer a sub-beam's plane moves sideways (bilinear, three
 * taps per axis: the NumPy twin's plane shift, or its gathers for shifts over a cell), then on the
 * layer's non-empty voxels loses exp(-tau) to what is caught and gains the voxels' emission that
 * escapes (exponential source profile plus its P2 term), with the moments of what is caught;
 * elsewhere the beams pass and the outputs are zero (no zeroing pass in Python).  Arrays in the
 * grid's layout are addressed through element strides in sweep order (layer, row, column).  In
 * each row only the span of non-empty voxels is transported (an empty voxel passes the beams
 * unchanged and holds no emission: the NumPy twin's rectangles give the same numbers), and a
 * layer's spans are gathered one after another into contiguous buffers, so the arithmetic runs as
 * one long vector loop per sub-beam and layer (row by row, each row's vector remainder, setup and
 * bookkeeping cost as much as the arithmetic).  float32 as the NumPy twin; the exponentials are
 * scatter_math.h's, so the two agree to a few float32 ulps per step, not bit for bit.  Plain C11
 * and libm, no threads (see native/build.py).  The x86-64-v4 clone (AVX-512: 32 vector registers,
 * masked remainders) gives the same numbers as the others (no fused multiply-adds anywhere:
 * tests/native/test_wine.py) and ran the Fig. 6 cloud's sweeps 1.4x as fast as the x86-64-v3 one.
 */

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "scatter_escape.h"
#include "scatter_math.h"

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
/* The profile rows' escapes on interleaved lanes (scatter_escape_lanes.h), except where the AVX-512
 * clone runs; measured on Linux x86-64 only, so the other builds keep the plain loop. */
#define LANE_ROWS 1
#include "scatter_escape_lanes.h"
#else
#define CLONES
#define LANE_ROWS 0
#endif

#define INLINE static inline __attribute__((always_inline))

/* Mirrored by nephele.core.light._native.SweepArgs (same order, all 8-byte fields). */
struct nph_sweep {
    int64_t L, A, B, sign, periodic_a, periodic_b, comp;
    const float *sig;     /* (L, A, B) contiguous, sweep order */
    const int64_t *spans; /* (L, A, 2): columns [b0, b1) of each row's non-empty voxels; b0 == b1: none */
    const int64_t *soff;  /* (L A + 1): each row's span's offset in a beam's cache row */
    int64_t g, ns;        /* bins of the group, sub-beams per bin: beam j = bin * ns + sub */
    const int64_t *ia, *ib; /* per beam: the plane shift's centre tap offset along a and b */
    const float *wa, *wb;   /* per beam: (previous, centre, next) tap weights along a and b */
    const float *cross;     /* (beams, 3): move across a voxel's unit cube per layer (x y z) */
    const float *ell, *w, *inflow; /* per beam: path across a layer, share of its bin's emission, inflow */
    const float *em;
    int64_t em_s[4];      /* (bin, layer, row, column) or NULL: emission */
    const float *kap;
    int64_t kap_s[4];     /* (xyz component, layer, row, column) or NULL: the profiles' rates */
    const float *qa;
    int64_t qa_s[3];      /* P2 weight along the sweep axis, or NULL */
    const float *var;
    int64_t var_s[3];     /* the profile's variance along the sweep axis (second moments), or NULL */
    float *recv;
    int64_t recv_s[5];    /* (bin, sub, layer, row, column): caught (sub stride used if per_sub) */
    int64_t per_sub;
    float *total;
    int64_t total_s[4];   /* (bin, layer, row, column) or NULL: not summed */
    double *exit_power;   /* (bins,) */
    float *mom;
    int64_t mom_s[5];     /* (bin, slot, layer, row, column) or NULL */
    int64_t slot_kept, slot_m2, slot_dep; /* -1: not tracked; slot 0 is the first moment */
    float *cache;         /* (3, beams, soff[L A]): escapes, kept shifts, kept second moments */
    int64_t cache_mode;   /* 0: none, 1: compute and store, 2: read */
    const int64_t *obins; /* (bins,) or NULL: total (and rbin) are the solve's arrays of all bins, this
                             group's bin ``bin`` being row obins[bin]; the total is added to them */
    float *rbin;
    int64_t rbin_s[4];    /* (bin, layer, row, column) or NULL: per_sub's catch summed over the sub-beams */
    double *caught;       /* (beams,) or NULL: the power each sub-beam caught (per_sub) */
    int64_t stage_min;    /* voxels in a layer (A B) from which arrays whose layers lie next to one
                             another are staged (see struct arr) */
    int64_t dark_zero;    /* the outputs (recv, rbin, mom) already hold zero at every voxel outside
                             this sweep's spans: they are not zeroed first (zero_outputs) */
    const float *shared;  /* (6, soff[L A]): the inputs every bin shares on the spans, laid out as a beam's
                             cache row (scatter_shared fills it before the bins are swept) */
};

/* Buffers of one layer's spans, one after another (soff's layout), and a row of the inflow; pe, ps,
 * pk, pt: a profile's escapes, shifts, kept second moments and transmittances (see row_escapes); sg,
 * k0-k2, qa, var: the layer's rows of the inputs all bins share (pointers into s->shared). */
struct rows {
    float *sg, *cur, *em, *k0, *k1, *k2, *qa, *var, *r, *rsum, *etot, *m1, *mk, *m2, *md, *pe, *ps, *pk, *pt, *inrow;
    int64_t *cols; /* (A, 2): a staged block's columns per row (stage_blocks) */
};

/* ------------------------------------------------------------------ one sub-beam across one row */

enum { NONE = 0, PLAIN = 1, PROFILE = 2, CACHED = 3 };

/* Sub-beam j's escapes of the profiled emission on the row's n cells: the escape fraction ``ce``,
 * where what a source keeps sits (``cs``, MOM) and its second moment (``ck``, M2), and the
 * transmittance ``ct``.  A loop of its own, before the transport (row_sub): one loop doing both held
 * about 150 vector operations per 8 voxels in chains of exponentials and divisions, more than the
 * out-of-order window of a Zen core overlaps, and ran at about 35 cycles a voxel. */
INLINE void row_escapes(const struct nph_sweep *s, int64_t j, int64_t n, const float *restrict sg,
                        const float *restrict k0, const float *restrict k1, const float *restrict k2,
                        const float *restrict qa, const float *restrict vr, float *restrict ce, float *restrict cs,
                        float *restrict ck, float *restrict ct, const int QA, const int MOM, const int M2)
{
    const float ell = s->ell[j];
    const float c0 = s->cross[3 * j], c1 = s->cross[3 * j + 1], c2 = s->cross[3 * j + 2];
    int64_t i = 0;
#if LANE_ROWS
    if (!__builtin_cpu_supports("avx512f"))
        for (; i + NPH_LANES * NPH_VW <= n; i += NPH_LANES * NPH_VW)
            nph_vrow_escapes(i, ell, c0, c1, c2, sg, k0, k1, k2, qa, vr, ce, cs, ck, ct, QA, MOM, M2);
#endif
    for (; i < n; i++) {
        float tau = sg[i] * ell;
        float t = nph_expf(-tau);
        float esc, vs = 0.5f, shift = 0.0f, kept2 = 0.0f;
        escape_centroid(tau, c0 * k0[i] + c1 * k1[i] + c2 * k2[i], t, &esc, &vs);
        if (QA)
            esc = nph_clampf(esc + qa[i] * p2_escape(tau, t), 0.0f, 1.0f);
        if (MOM) {
            /* what a source keeps sits downstream of it (the NumPy twin's comments) */
            float kept = nph_maxf(1.0f - esc, 1e-30f), tm = nph_maxf(tau, 1e-2f);
            shift = ((vs - esc) * tm + kept) / (kept * tm) - vs; /* (vs - esc) / kept + 1 / tm - vs */
            shift = nph_clampf(shift, -1.0f, 1.0f);
            shift = tau < 1e-2f ? 1.0f / 6 : shift;
            if (M2) {
                float ti = 1.0f / nph_maxf(tau, 0.1f);
                float m2s = vr[i] + (vs - 0.5f) * (vs - 0.5f);
                kept2 = m2s + (vs + vs - 1.0f - esc) * ti + 2.0f * kept * ti * ti - 0.25f * esc;
                kept2 = tau < 0.1f ? kept * m2s : kept2;
                kept2 = nph_clampf(kept2, 0.0f, 0.25f * kept);
            }
        }
        ce[i] = esc;
        cs[i] = shift;
        ck[i] = kept2;
        ct[i] = t;
    }
}

/* Transport sub-beam j's row ``cur`` (n cells) through the layer's row (extinction ``sg``, the row
 * buffers of struct rows): emission ``mode`` (NONE: no emission; PLAIN: spread evenly; PROFILE: its
 * profile, whose escapes row_escapes wrote to ce, cs, ck and the transmittances to ct, or CACHED: the
 * escapes read from ce, cs, ck), ``MOM`` the moments (``M2`` second).  What is caught goes to ``r``,
 * the rest accumulates over the bin's sub-beams. */
INLINE void row_sub(const struct nph_sweep *s, int64_t j, int64_t n, const float *restrict sg, float *restrict cur,
                    const float *restrict em, float *restrict r, float *restrict etot, float *restrict m1,
                    float *restrict mk, float *restrict m2, float *restrict md, const float *restrict ce,
                    const float *restrict cs, const float *restrict ck, const float *restrict ct, const int mode,
                    const int MOM, const int M2)
{
    /* (the arrays as restrict parameters: GCC gives up on a loop needing more than 10 run-time
     * alias checks, and restrict locals did not stop them) */
    const float ell = s->ell[j], wj = s->w[j];
    const float cw = s->cross[3 * j + s->comp];
    for (int64_t i = 0; i < n; i++) {
        float tau = sg[i] * ell;
        float t = mode == PROFILE ? ct[i] : nph_expf(-tau);
        float bm = cur[i], bt = bm * t, rb = bm - bt;
        float e = 0.0f, re = 0.0f, esc = 0.0f, shift = 0.0f, kept2 = 0.0f, ri;
        if (mode == NONE) {
            ri = rb;
            cur[i] = bt;
        } else {
            if (mode == PLAIN) {
                esc = nph_phif(tau);
            } else {
                esc = ce[i];
                shift = cs[i];
                kept2 = ck[i];
            }
            e = em[i] * wj;
            float ee = e * esc;
            re = e - ee;
            ri = rb + re;
            cur[i] = bt + ee;
            etot[i] += e;
        }
        if (MOM) {
            float offb = offset_pos(tau, t);
            float dep = rb * offb;
            if (mode >= PROFILE) {
                mk[i] += re;
                dep += re * shift;
            }
            m1[i] += cw * dep;
            if (M2) {
                float dep2 = rb * (variance(tau, t) + offb * offb);
                if (mode >= PROFILE)
                    dep2 += e * kept2;
                m2[i] += dep2;
                md[i] += rb;
            }
        }
        r[i] = ri;
    }
}

/* Each specialization of row_sub is a function of its own, with its own clones.  Inlined into the
 * sweep, whether GCC vectorized the hot ones hung on unrelated code: renaming a zeroing helper
 * left the v4 clone's profile rows scalar and the sweeps 4x as slow.  A profile's escapes go to the
 * cache (``STORE``) or the rows' buffers pe, ps, pk (ce NULL), its P2 term ``QA``. */
#define ROW_KERNEL(MODE, QA, MOM, M2, STORE)                                                                      \
    CLONES __attribute__((noinline)) static void row_##MODE##_##QA##MOM##M2##STORE(                                \
        const struct nph_sweep *s, int64_t j, int64_t n, const float *sg, float *cur, const struct rows *rw,        \
        float *ce, float *cs, float *ck)                                                                           \
    {                                                                                                              \
        if (MODE == PROFILE && !STORE) {                                                                           \
            ce = rw->pe;                                                                                           \
            cs = rw->ps;                                                                                           \
            ck = rw->pk;                                                                                           \
        }                                                                                                          \
        if (MODE == PROFILE)                                                                                       \
            row_escapes(s, j, n, sg, rw->k0, rw->k1, rw->k2, rw->qa, rw->var, ce, cs, ck, rw->pt, QA, MOM, M2);    \
        row_sub(s, j, n, sg, cur, rw->em, rw->r, rw->etot, rw->m1, rw->mk, rw->m2, rw->md, ce, cs, ck, rw->pt,      \
                MODE, MOM, M2);                                                                                    \
    }
ROW_KERNEL(NONE, 0, 0, 0, 0)
ROW_KERNEL(PLAIN, 0, 0, 0, 0)
ROW_KERNEL(CACHED, 0, 0, 0, 0)
ROW_KERNEL(NONE, 0, 1, 0, 0)
ROW_KERNEL(PLAIN, 0, 1, 0, 0)
ROW_KERNEL(CACHED, 0, 1, 0, 0)
ROW_KERNEL(NONE, 0, 1, 1, 0)
ROW_KERNEL(PLAIN, 0, 1, 1, 0)
ROW_KERNEL(CACHED, 0, 1, 1, 0)
ROW_KERNEL(PROFILE, 0, 0, 0, 0)
ROW_KERNEL(PROFILE, 0, 0, 0, 1)
ROW_KERNEL(PROFILE, 1, 0, 0, 0)
ROW_KERNEL(PROFILE, 1, 0, 0, 1)
ROW_KERNEL(PROFILE, 0, 1, 0, 0)
ROW_KERNEL(PROFILE, 0, 1, 0, 1)
ROW_KERNEL(PROFILE, 1, 1, 0, 0)
ROW_KERNEL(PROFILE, 1, 1, 0, 1)
ROW_KERNEL(PROFILE, 0, 1, 1, 0)
ROW_KERNEL(PROFILE, 0, 1, 1, 1)
ROW_KERNEL(PROFILE, 1, 1, 1, 0)
ROW_KERNEL(PROFILE, 1, 1, 1, 1)

#define ROW(MODE, QA, MOM, M2, STORE) row_##MODE##_##QA##MOM##M2##STORE(s, j, n, sg, cur, rw, ce, cs, ck)

INLINE void row_dispatch(const struct nph_sweep *s, int64_t j, const float *sg, float *cur, const struct rows *rw,
                         float *ce, float *cs, float *ck, int64_t n, int mode, int qa, int mom, int m2, int store)
{
    if (mode == NONE || mode == PLAIN || mode == CACHED) {
        if (!mom)
            mode == NONE ? ROW(NONE, 0, 0, 0, 0) : mode == PLAIN ? ROW(PLAIN, 0, 0, 0, 0) : ROW(CACHED, 0, 0, 0, 0);
        else if (!m2)
            mode == NONE ? ROW(NONE, 0, 1, 0, 0) : mode == PLAIN ? ROW(PLAIN, 0, 1, 0, 0) : ROW(CACHED, 0, 1, 0, 0);
        else
            mode == NONE ? ROW(NONE, 0, 1, 1, 0) : mode == PLAIN ? ROW(PLAIN, 0, 1, 1, 0) : ROW(CACHED, 0, 1, 1, 0);
        return;
    }
    if (!mom) {
        qa ? (store ? ROW(PROFILE, 1, 0, 0, 1) : ROW(PROFILE, 1, 0, 0, 0))
           : (store ? ROW(PROFILE, 0, 0, 0, 1) : ROW(PROFILE, 0, 0, 0, 0));
    } else if (!m2) {
        qa ? (store ? ROW(PROFILE, 1, 1, 0, 1) : ROW(PROFILE, 1, 1, 0, 0))
           : (store ? ROW(PROFILE, 0, 1, 0, 1) : ROW(PROFILE, 0, 1, 0, 0));
    } else {
        qa ? (store ? ROW(PROFILE, 1, 1, 1, 1) : ROW(PROFILE, 1, 1, 1, 0))
           : (store ? ROW(PROFILE, 0, 1, 1, 1) : ROW(PROFILE, 0, 1, 1, 0));
    }
}

/* ------------------------------------------------------------------ plane shifts */

/* index c of an axis of n cells: wrapped (periodic) or -1 (outside: the inflow) */
static inline int64_t axis_index(int64_t c, int64_t n, int64_t periodic)
{
    if (c >= 0 && c < n)
        return c;
    if (!periodic)
        return -1;
    c %= n;
    return c < 0 ? c + n : c;
}

/* o[c] = wc x[c] + wm x[c - d] + wp x[c + d] for c in [0, n): one tap step of a plane shift over a run
 * of whole rows (d = B) or of a plane read as one long row (d = 1) */
INLINE void taps(float *restrict o, const float *x, int64_t d, int64_t n, float wm, float wc, float wp)
{
    for (int64_t c = 0; c < n; c++)
        o[c] = wc * x[c] + wm * x[c - d] + wp * x[c + d];
}

/* x[q] of a row of B, or what lies beyond its ends: the row wrapped (periodic) or the inflow */
static inline float ghost(const float *x, int64_t q, int64_t B, int64_t periodic, const float *inrow)
{
    int64_t i = axis_index(q, B, periodic);
    return i < 0 ? inrow[0] : x[i];
}

/* new[c] = wc old[c - i0] + wm old[c - i0 - 1] + wp old[c - i0 + 1] along a (rows) into tmp, then
 * along b (columns) back into p; the inflow outside non-periodic sides.  The rows whose three taps
 * all fall inside the plane go as one run, and along b the plane is read as one long row, its
 * columns whose taps cross a row's end (all of them for shifts of about a row) then redone from
 * that row with its ghost cells: long loops (rows of 38 or 46 columns left a vector loop's
 * remainder each), the same sums. */
INLINE void shift_plane(const struct nph_sweep *s, int64_t j, float *restrict p, float *restrict tmp,
                        const float *restrict inrow)
{
    const int64_t A = s->A, B = s->B;
    const float wm = s->wa[3 * j], wc = s->wa[3 * j + 1], wp = s->wa[3 * j + 2];
    const int64_t i0 = s->ia[j];
    int64_t r0 = i0 + 1 < 0 ? 0 : i0 + 1, r1 = A + i0 - 1 > A ? A : A + i0 - 1; /* rows with all taps inside */
    if (r1 <= r0)
        r0 = r1 = 0;
    else
        taps(tmp + r0 * B, p + (r0 - i0) * B, B, (r1 - r0) * B, wm, wc, wp);
    for (int64_t a = 0; a < A; a++) {
        if (a == r0 && r1 > r0) {
            a = r1 - 1;
            continue;
        }
        int64_t ic = axis_index(a - i0, A, s->periodic_a), im = axis_index(a - i0 - 1, A, s->periodic_a),
                ip = axis_index(a - i0 + 1, A, s->periodic_a);
        const float *xc = ic < 0 ? inrow : p + ic * B, *xm = im < 0 ? inrow : p + im * B,
                    *xp = ip < 0 ? inrow : p + ip * B;
        float *restrict o = tmp + a * B;
        for (int64_t b = 0; b < B; b++)
            o[b] = wc * xc[b] + wm * xm[b] + wp * xp[b];
    }
    const float vm = s->wb[3 * j], vc = s->wb[3 * j + 1], vp = s->wb[3 * j + 2];
    const int64_t j0 = s->periodic_b ? ((s->ib[j] % B) + B) % B : s->ib[j];
    int64_t c0 = 0, c1 = 0; /* the columns [c0, c1) of every row whose taps stay in the row */
    if (j0 + 1 < B - 1 && -j0 + 1 < B - 1) {
        c0 = j0 + 1 > 0 ? j0 + 1 : 0;
        c1 = B + j0 - 1 < B ? B + j0 - 1 : B;
        /* as one long row: the columns outside [c0, c1) are overwritten below */
        taps(p + c0, tmp + c0 - j0, 1, A * B - c0 - (B - c1), vm, vc, vp);
    }
    for (int64_t a = 0; a < A; a++) { /* the columns whose taps cross the row's ends */
        const float *x = tmp + a * B;
        float *restrict o = p + a * B;
        for (int64_t b = 0; b < B; b++) {
            if (b == c0 && c1 > c0)
                b = c1;
            if (b < B)
                o[b] = vc * ghost(x, b - j0, B, s->periodic_b, inrow) + vm * ghost(x, b - j0 - 1, B, s->periodic_b, inrow)
                       + vp * ghost(x, b - j0 + 1, B, s->periodic_b, inrow);
        }
    }
}

/* ------------------------------------------------------------------ rows of strided arrays */

static void gather(float *restrict dst, const float *src, int64_t stride, int64_t n)
{
    if (stride == 1)
        memcpy(dst, src, (size_t)n * sizeof *dst);
    else
        for (int64_t i = 0; i < n; i++)
            dst[i] = src[i * stride];
}

static void scatter_row(float *dst, int64_t stride, const float *restrict src, int64_t n)
{
    if (stride == 1)
        memcpy(dst, src, (size_t)n * sizeof *dst);
    else
        for (int64_t i = 0; i < n; i++)
            dst[i * stride] = src[i];
}

static void zero_row(float *dst, int64_t stride, int64_t n)
{
    if (stride == 1)
        memset(dst, 0, (size_t)n * sizeof *dst);
    else
        for (int64_t i = 0; i < n; i++)
            dst[i * stride] = 0.0f;
}

/* sum of a row in float64, eight running sums (one would wait on each addition's latency) */
INLINE double row_sum(const float *restrict x, int64_t n)
{
    double part[8] = {0.0};
    int64_t i = 0;
    for (; i + 8 <= n; i += 8)
        for (int q = 0; q < 8; q++)
            part[q] += x[i + q];
    for (; i < n; i++)
        part[0] += x[i];
    return ((part[0] + part[1]) + (part[2] + part[3])) + ((part[4] + part[5]) + (part[6] + part[7]));
}

/* The size of the block the n axes (dims, element strides) address, or 0 unless it is dense (every
 * element once, none between, lowest address first): such an output is zeroed by one memset per
 * bin, not row by row outside the spans (1216 memsets a layer for 16 sub-beams' catches). */
static int64_t dense_size(int n, const int64_t *dims, const int64_t *st)
{
    int64_t d[5], t[5], m = 0, size = 1;
    for (int i = 0; i < n; i++)
        if (dims[i] > 1) {
            int64_t j = m++;
            for (; j > 0 && t[j - 1] > st[i]; j--) { /* insertion sort by stride, innermost first */
                d[j] = d[j - 1];
                t[j] = t[j - 1];
            }
            d[j] = dims[i];
            t[j] = st[i];
        }
    for (int64_t i = 0; i < m; size *= d[i], i++)
        if (t[i] != size)
            return 0;
    return size;
}

/* Zero the bin's outputs (catch, catch summed over sub-beams, moments) as whole blocks; 0 (nothing
 * written) unless every one of them is dense.  1 at once where they hold zero outside the spans
 * already (dark_zero): the solve's outputs, which no sweep ever writes anything but zero outside
 * its spans (an empty voxel, tau 0, catches nothing of a beam and holds no emission). */
static int zero_outputs(const struct nph_sweep *s, float *rec, float *rb, float *mo, int64_t nslots)
{
    if (s->dark_zero)
        return 1;
    const int64_t nrecv = s->per_sub ? s->ns : 1;
    int64_t rd[4] = {nrecv, s->L, s->A, s->B}, md[3] = {s->L, s->A, s->B};
    int64_t nr = dense_size(4, rd, s->recv_s + 1), nb = rb == NULL ? 0 : dense_size(3, md, s->rbin_s + 1);
    int64_t nm = nslots ? dense_size(3, md, s->mom_s + 2) : 0;
    if (nr == 0 || (rb != NULL && nb == 0) || (nslots && nm == 0))
        return 0;
    memset(rec, 0, (size_t)nr * sizeof(float));
    if (rb != NULL)
        memset(rb, 0, (size_t)nb * sizeof(float));
    for (int64_t sl = 0; sl < nslots; sl++)
        memset(mo + sl * s->mom_s[1], 0, (size_t)nm * sizeof(float));
    return 1;
}

/* ------------------------------------------------------------------ layers, in place or staged */

/* One layer of an array: element (a, b) at p[a * rs + b * cs]. */
struct lay {
    float *p;
    int64_t rs, cs;
};

/* An array addressed by (layer, row, column) element strides ``st`` (NULL base: absent).  Where its
 * layers lie next to one another in memory (st[0] == 1: the sweeps along the grid's x axis) each
 * element of a layer's rows sits in a cache line of its own, and at 128x128x96 the lines had left
 * the cache before the next layer used them (x sweeps took 1.7-2.6x as long as the others): such
 * an array goes through ``stage`` (KB, A, B) in blocks of KB layers, copied in or out a cache line
 * at a time, where a layer holds at least stage_min voxels.  ``add``: an output added to the
 * array (the solve's total). */
struct arr {
    float *base;
    const int64_t *st;
    float *stage; /* NULL: used in place */
    int add;
};

#define KB 16     /* layers in a staged block: 64 bytes of float32 */
#define MAXREC 16 /* catches staged per bin at most (more sub-beams: in place) */

/* x is staged: its layers lie next to one another, and they are big enough (stage_min) */
static int staged(const struct nph_sweep *s, const struct arr *x)
{
    return x->base != NULL && x->st[0] == 1 && x->st[2] != 1 && s->A * s->B >= s->stage_min;
}

/* layer k of x, whose staged block starts at layer klo */
static struct lay view(const struct arr *x, int64_t k, int64_t klo, int64_t A, int64_t B)
{
    if (x->stage != NULL)
        return (struct lay){x->stage + (k - klo) * A * B, B, 1};
    if (x->base != NULL)
        return (struct lay){x->base + k * x->st[0], x->st[1], x->st[2]};
    return (struct lay){NULL, 0, 0};
}

/* columns [*u0, *u1) of row a holding a span in some layer of [klo, klo + nk) ((0, 0): none) */
static void union_span(const struct nph_sweep *s, int64_t a, int64_t klo, int64_t nk, int64_t *u0, int64_t *u1)
{
    int64_t lo = s->B, hi = 0;
    for (int64_t k = klo; k < klo + nk; k++) {
        const int64_t b0 = s->spans[2 * (k * s->A + a)], b1 = s->spans[2 * (k * s->A + a) + 1];
        if (b1 > b0) {
            lo = b0 < lo ? b0 : lo;
            hi = b1 > hi ? b1 : hi;
        }
    }
    *u0 = hi > lo ? lo : 0;
    *u1 = hi > lo ? hi : 0;
}

enum { STAGE_IN, STAGE_ZERO, STAGE_OUT };

/* Block [klo, klo + nk) of a staged array on its rows' spans (``cols``: row a's columns [cols[2a],
 * cols[2a + 1]) holding a span in some layer of the block; ``full``: whole rows): copied into the
 * stage, the stage zeroed (an output), or the stage copied (added) back.  Layer by layer, so the
 * stage's side is one stream along the layer, and the array's side steps through each row's cache
 * lines (a line holds the block's 16 layers).  (Column by column, the stage's side was 16 short
 * streams, one per layer: the copies took 7.3 % of the CPU of the 128x128x96 solve, now 4.3 %.) */
static void stage_block(const struct nph_sweep *s, const struct arr *x, int64_t nk, int full, int how,
                        const int64_t *cols)
{
    const int64_t A = s->A, B = s->B, AB = A * B, cs = x->st[2];
    for (int64_t q = 0; q < nk; q++)
        for (int64_t a = 0; a < A; a++) {
            const int64_t u0 = full ? 0 : cols[2 * a], n = full ? B : cols[2 * a + 1] - u0;
            float *restrict t = x->stage + q * AB + a * B + u0, *m = x->base + q + a * x->st[1] + u0 * cs;
            if (how == STAGE_IN)
                for (int64_t b = 0; b < n; b++)
                    t[b] = m[b * cs];
            else if (how == STAGE_ZERO)
                for (int64_t b = 0; b < n; b++)
                    t[b] = 0.0f;
            else if (x->add)
                for (int64_t b = 0; b < n; b++)
                    m[b * cs] += t[b];
            else
                for (int64_t b = 0; b < n; b++)
                    m[b * cs] = t[b];
        }
}

/* A bin's arrays: input (emission; the inputs all bins share are in s->shared), outputs
 * (per_sub's summed catch, up to four moment slots, the total), and the catch: one array per
 * sub-beam (per_sub) at rec.base + q * rec_q, stage rec.stage + q KB A B, or one. */
enum { EM, RBIN, MOM0, TOT = MOM0 + 4, NARR };
struct bin_arrays {
    struct arr x[NARR], rec;
    int64_t rec_q, nrec;
};

/* The bin's arrays, those whose layers are adjacent staged in ``stage`` (NULL: none); the outputs
 * only where ``zeroed`` (their blocks were zeroed whole: a staged block writes back the union of
 * its layers' spans, not each layer's). */
static void bin_arrays(const struct nph_sweep *s, int64_t bin, float *stage, int zeroed, struct bin_arrays *ba)
{
    const int64_t KAB = KB * s->A * s->B, ob = s->obins == NULL ? bin : s->obins[bin];
    struct arr *x = ba->x;
    for (int i = 0; i < NARR; i++)
        x[i] = (struct arr){NULL, NULL, NULL, 0};
    if (s->em != NULL)
        x[EM] = (struct arr){(float *)s->em + bin * s->em_s[0], s->em_s + 1, NULL, 0};
    if (s->rbin != NULL)
        x[RBIN] = (struct arr){s->rbin + ob * s->rbin_s[0], s->rbin_s + 1, NULL, 0};
    const int64_t slots[4] = {0, s->slot_kept, s->slot_m2, s->slot_dep};
    for (int f = 0; f < 4 && s->mom != NULL; f++)
        if (slots[f] >= 0)
            x[MOM0 + f] = (struct arr){s->mom + bin * s->mom_s[0] + slots[f] * s->mom_s[1], s->mom_s + 2, NULL, 0};
    if (s->total != NULL)
        x[TOT] = (struct arr){s->total + ob * s->total_s[0], s->total_s + 1, NULL, s->obins != NULL};
    ba->nrec = s->per_sub ? s->ns : 1;
    ba->rec_q = s->recv_s[1];
    ba->rec = (struct arr){s->recv + bin * s->recv_s[0], s->recv_s + 2, NULL, 0};
    if (stage == NULL)
        return;
    for (int i = 0; i < NARR; i++)
        if (staged(s, &x[i]) && (i < RBIN || i == TOT || zeroed))
            x[i].stage = stage + i * KAB;
    if (staged(s, &ba->rec) && ba->nrec <= MAXREC && zeroed)
        ba->rec.stage = stage + NARR * KAB;
}

/* sub-beam q's catch */
static struct arr rec_arr(const struct bin_arrays *ba, int64_t q, int64_t KAB)
{
    struct arr r = ba->rec;
    r.base += q * ba->rec_q;
    if (r.stage != NULL)
        r.stage += q * KAB;
    return r;
}

/* The staged arrays of block [klo, klo + nk): in (inputs copied, outputs zeroed) or out; ``cols``
 * (2 A; NULL: nothing is staged): the block's columns per row, which all its arrays share, found on
 * the way in and still there on the way out */
static void stage_blocks(const struct nph_sweep *s, const struct bin_arrays *ba, int64_t klo, int64_t nk, int in,
                         int64_t *cols)
{
    const int64_t KAB = KB * s->A * s->B;
    if (cols == NULL) /* (no stages) */
        return;
    for (int64_t a = 0; a < s->A && in; a++)
        union_span(s, a, klo, nk, &cols[2 * a], &cols[2 * a + 1]);
    for (int i = 0; i < NARR; i++)
        if (ba->x[i].stage != NULL && (in || i >= RBIN)) {
            struct arr x = ba->x[i];
            x.base += klo;
            stage_block(s, &x, nk, i == TOT, i < RBIN ? STAGE_IN : in ? STAGE_ZERO : STAGE_OUT, cols);
        }
    for (int64_t q = 0; q < ba->nrec && ba->rec.stage != NULL; q++) {
        struct arr r = rec_arr(ba, q, KAB);
        r.base += klo;
        stage_block(s, &r, nk, 0, in ? STAGE_ZERO : STAGE_OUT, cols);
    }
}

/* Floats of the stages: none unless some array of the group has its layers next to one another. */
static int64_t stage_size(const struct nph_sweep *s)
{
    struct bin_arrays ba;
    bin_arrays(s, 0, NULL, 0, &ba);
    int any = staged(s, &ba.rec);
    for (int i = 0; i < NARR; i++)
        any |= staged(s, &ba.x[i]);
    return any ? (NARR + MAXREC) * KB * s->A * s->B : 0;
}

/* row a of a layer zeroed outside columns [lo, hi) */
static void zero_outside(struct lay v, int64_t a, int64_t lo, int64_t hi, int64_t B)
{
    zero_row(v.p + a * v.rs, v.cs, lo);
    zero_row(v.p + a * v.rs + hi * v.cs, v.cs, B - hi);
}

/* row a's columns [b0, b0 + n) of a layer gathered into dst, or scattered from src */
static void gather_lay(float *dst, struct lay v, int64_t a, int64_t b0, int64_t n)
{
    gather(dst, v.p + a * v.rs + b0 * v.cs, v.cs, n);
}
static void scatter_lay(struct lay v, int64_t a, int64_t b0, const float *src, int64_t n)
{
    scatter_row(v.p + a * v.rs + b0 * v.cs, v.cs, src, n);
}

/* row a of the total: written, or added to the solve's (obins) */
static void put_total(const struct nph_sweep *s, struct lay t, int64_t a, const float *restrict src, int64_t n)
{
    float *dst = t.p + a * t.rs;
    if (s->obins == NULL)
        scatter_row(dst, t.cs, src, n);
    else if (t.cs == 1) /* (a loop of its own: the strided one does not vectorize) */
        for (int64_t i = 0; i < n; i++)
            dst[i] += src[i];
    else
        for (int64_t i = 0; i < n; i++)
            dst[i * t.cs] += src[i];
}

/* ------------------------------------------------------------------ one bin */

/* Layer k's rows: outputs zero outside each row's span (a row without one: all zero, its total the
 * entering beams) unless ``zeroed`` (the bin's outputs were zeroed as blocks), the emission on the
 * spans gathered into the layer's buffer one after another (row a's at soff[k A + a] - soff[k A], as
 * the shared inputs lie), so the arithmetic runs once per sub-beam over the whole layer. */
INLINE void layer_rows(const struct nph_sweep *s, int64_t k, int64_t klo, const float *tmp,
                       const struct bin_arrays *ba, int zeroed, struct rows *rw, int mode)
{
    const int64_t A = s->A, B = s->B, AB = A * B, base = s->soff[k * A];
    const struct lay tot = view(&ba->x[TOT], k, klo, A, B);
    const struct lay em = view(&ba->x[EM], k, klo, A, B);
    for (int64_t a = 0; a < A; a++) {
        const int64_t b0 = s->spans[2 * (k * A + a)], b1 = s->spans[2 * (k * A + a) + 1], wd = b1 - b0;
        const int64_t lo = wd > 0 ? b0 : B, hi = wd > 0 ? b1 : B; /* zero outside [lo, hi) */
        for (int i = RBIN; i < TOT && !zeroed; i++)
            if (ba->x[i].base != NULL)
                zero_outside(view(&ba->x[i], k, klo, A, B), a, lo, hi, B);
        for (int64_t q = 0; q < ba->nrec && !zeroed; q++) {
            const struct arr r = rec_arr(ba, q, KB * AB);
            zero_outside(view(&r, k, klo, A, B), a, lo, hi, B);
        }
        if (wd <= 0) {
            if (tot.p != NULL)
                put_total(s, tot, a, tmp + a * B, B);
            continue;
        }
        if (mode != NONE)
            gather_lay(rw->em + s->soff[k * A + a] - base, em, a, b0, wd);
    }
}

/* Sub-beam j's plane (q's) through layer k: its spans copied out, transported as one row, copied
 * back; what it caught per row to its own catch ``rec`` (per_sub, with the power it caught) and
 * summed. */
INLINE void layer_sub(const struct nph_sweep *s, int64_t bin, int64_t q, int64_t k, int64_t S, float *plane,
                      struct lay rec, struct rows *rw, int mode, int qa, int mom, int m2, int store, int sum)
{
    const int64_t A = s->A, B = s->B, base = s->soff[k * A], j = bin * s->ns + q;
    for (int64_t a = 0; a < A; a++) {
        const int64_t b0 = s->spans[2 * (k * A + a)], wd = s->spans[2 * (k * A + a) + 1] - b0;
        if (wd > 0)
            memcpy(rw->cur + s->soff[k * A + a] - base, plane + a * B + b0, (size_t)wd * sizeof(float));
    }
    float *ce = NULL, *cs = NULL, *ck = NULL;
    if (s->cache_mode) {
        const int64_t beams = s->g * s->ns, span = s->soff[s->L * A];
        ce = s->cache + j * span + base;
        cs = ce + beams * span;
        ck = cs + beams * span;
    }
    row_dispatch(s, j, rw->sg, rw->cur, rw, ce, cs, ck, S, mode, qa, mom, m2, store);
    for (int64_t a = 0; a < A; a++) {
        const int64_t b0 = s->spans[2 * (k * A + a)], wd = s->spans[2 * (k * A + a) + 1] - b0;
        if (wd <= 0)
            continue;
        const int64_t o = s->soff[k * A + a] - base;
        memcpy(plane + a * B + b0, rw->cur + o, (size_t)wd * sizeof(float));
        if (s->per_sub) {
            scatter_lay(rec, a, b0, rw->r + o, wd);
            if (s->caught != NULL)
                s->caught[j] += row_sum(rw->r + o, wd);
        }
    }
    if (sum)
        for (int64_t i = 0; i < S; i++)
            rw->rsum[i] += rw->r[i];
}

/* Layer k's S non-empty voxels: every sub-beam through them, then the summed catch, the moments
 * and the total (the entering beams in ``tmp`` plus the emission) written on the rows. */
INLINE void layer_end(const struct nph_sweep *s, int64_t bin, int64_t k, int64_t klo, int64_t S, float *planes,
                      float *tmp, const struct bin_arrays *ba, struct rows *rw, int mode, int qa, int mom, int m2,
                      int store)
{
    const int64_t A = s->A, B = s->B, AB = A * B;
    const struct lay rb = view(&ba->x[RBIN], k, klo, A, B), tot = view(&ba->x[TOT], k, klo, A, B);
    float *zero[6] = {rw->etot, rw->rsum, rw->m1, rw->mk, rw->m2, rw->md};
    for (int f = 0; f < 6; f++)
        memset(zero[f], 0, (size_t)S * sizeof(float));
    for (int64_t q = 0; q < s->ns; q++) {
        const struct arr r = rec_arr(ba, s->per_sub ? q : 0, KB * AB);
        layer_sub(s, bin, q, k, S, planes + q * AB, view(&r, k, klo, A, B), rw, mode, qa, mom, m2, store,
                  !s->per_sub || rb.p != NULL);
    }
    const struct lay rec = view(&ba->rec, k, klo, A, B);
    const float *mf[4] = {rw->m1, rw->mk, rw->m2, rw->md}; /* slot fields in bin_arrays' order */
    struct lay mo[4];
    for (int f = 0; f < 4; f++)
        mo[f] = view(&ba->x[MOM0 + f], k, klo, A, B);
    for (int64_t a = 0; a < A; a++) {
        const int64_t b0 = s->spans[2 * (k * A + a)], wd = s->spans[2 * (k * A + a) + 1] - b0;
        if (wd <= 0)
            continue;
        const int64_t o = s->soff[k * A + a] - s->soff[k * A];
        if (!s->per_sub)
            scatter_lay(rec, a, b0, rw->rsum + o, wd);
        if (rb.p != NULL)
            scatter_lay(rb, a, b0, rw->rsum + o, wd);
        if (tot.p != NULL) {
            for (int64_t i = 0; i < wd; i++)
                tmp[a * B + b0 + i] += rw->etot[o + i];
            put_total(s, tot, a, tmp + a * B, B);
        }
        for (int f = 0; f < 4 && mom; f++)
            if (mo[f].p != NULL)
                scatter_lay(mo[f], a, b0, mf[f] + o, wd);
    }
}

INLINE void sweep_bin(const struct nph_sweep *s, int64_t bin, float *planes, float *tmp, struct rows *rw,
                      float *stage)
{
    const int64_t L = s->L, A = s->A, B = s->B, ns = s->ns, AB = A * B;
    const int64_t nslots = s->mom == NULL ? 0 : 1 + (s->slot_kept >= 0) + (s->slot_m2 >= 0) + (s->slot_dep >= 0);
    const int mode = s->em == NULL ? NONE : s->kap == NULL ? PLAIN : s->cache_mode == 2 ? CACHED : PROFILE;
    const int qa = s->qa != NULL, mom = s->mom != NULL, m2 = s->slot_m2 >= 0, store = s->cache_mode == 1;
    float *inrow = rw->inrow; /* (per sub-beam, refilled) */
    for (int64_t q = 0; q < ns; q++) {
        float v = s->inflow[bin * ns + q];
        for (int64_t c = 0; c < AB; c++)
            planes[q * AB + c] = v;
    }
    const int64_t ob = s->obins == NULL ? bin : s->obins[bin];
    float *rb = s->rbin == NULL ? NULL : s->rbin + ob * s->rbin_s[0];
    const int zeroed = zero_outputs(s, s->recv + bin * s->recv_s[0], rb, mom ? s->mom + bin * s->mom_s[0] : NULL,
                                    nslots);
    struct bin_arrays ba;
    bin_arrays(s, bin, stage, zeroed, &ba);
    int64_t klo = 0, nk = 0;
    for (int64_t n = 0; n < L; n++) {
        const int64_t k = s->sign > 0 ? n : L - 1 - n;
        if (n % KB == 0) {
            nk = L - n < KB ? L - n : KB;
            klo = s->sign > 0 ? n : L - n - nk;
            stage_blocks(s, &ba, klo, nk, 1, rw->cols);
        }
        if (n)
            for (int64_t q = 0; q < ns; q++) {
                float v = s->inflow[bin * ns + q];
                for (int64_t b = 0; b < B; b++)
                    inrow[b] = v;
                shift_plane(s, bin * ns + q, planes + q * AB, tmp, inrow);
            }
        if (s->total != NULL) { /* total: the beams entering the layer (the emission is added on the spans) */
            for (int64_t c = 0; c < AB; c++)
                tmp[c] = planes[c];
            for (int64_t q = 1; q < ns; q++)
                for (int64_t c = 0; c < AB; c++)
                    tmp[c] += planes[q * AB + c];
        }
        float *sh = (float *)s->shared + s->soff[k * A]; /* (the shared inputs read where they lie) */
        float **in[6] = {&rw->sg, &rw->k0, &rw->k1, &rw->k2, &rw->qa, &rw->var};
        for (int f = 0; f < 6; f++)
            *in[f] = sh + f * s->soff[L * A];
        layer_rows(s, k, klo, tmp, &ba, zeroed, rw, mode);
        const int64_t S = s->soff[(k + 1) * A] - s->soff[k * A];
        if (S > 0)
            layer_end(s, bin, k, klo, S, planes, tmp, &ba, rw, mode, qa, mom, m2, store);
        if (n % KB == KB - 1 || n == L - 1)
            stage_blocks(s, &ba, klo, nk, 0, rw->cols);
    }
    double ex = 0.0;
    for (int64_t c = 0; c < ns * AB; c++)
        ex += planes[c];
    s->exit_power[bin] = ex;
}

/* The inputs every bin of the group shares on layers [k_lo, k_hi)'s spans, into out (6, soff[L A]): the
 * medium, the profile's three rates, its P2 weight and variance (rows of absent inputs left as they
 * are), a layer's rows one after another as in a beam's cache row.  With s->shared pointing there,
 * scatter_sweep reads them in place, not gathered for each bin (a sweep of each group on the
 * Fig. 6 cloud's 128x128x96 box: 5 % faster with 4 sub-beams a bin, 8 % with one).  Python runs layer
 * ranges on its threads. */
CLONES
void scatter_shared(const struct nph_sweep *s, int64_t k_lo, int64_t k_hi, float *out)
{
    const int64_t A = s->A, B = s->B, T = s->soff[s->L * A];
    const float *src[6] = {s->sig, s->kap, s->kap == NULL ? NULL : s->kap + s->kap_s[0],
                           s->kap == NULL ? NULL : s->kap + 2 * s->kap_s[0], s->qa, s->var};
    const int64_t *st[6] = {NULL, s->kap_s + 1, s->kap_s + 1, s->kap_s + 1, s->qa_s, s->var_s};
    for (int f = 0; f < 6; f++) {
        if (src[f] == NULL)
            continue;
        for (int64_t k = k_lo; k < k_hi; k++)
            for (int64_t a = 0; a < A; a++) {
                const int64_t b0 = s->spans[2 * (k * A + a)], wd = s->spans[2 * (k * A + a) + 1] - b0;
                float *o = out + f * T + s->soff[k * A + a];
                if (wd <= 0)
                    continue;
                if (f == 0) /* (the medium: contiguous, sweep order) */
                    memcpy(o, s->sig + (k * A + a) * B + b0, (size_t)wd * sizeof(float));
                else
                    gather(o, src[f] + k * st[f][0] + a * st[f][1] + b0 * st[f][2], st[f][2], wd);
            }
    }
}

/* Floats of the workspace scatter_sweep needs: the sub-beams' planes, one more plane, the layer's
 * buffers (NBUF, a plane each), a row of the inflow, the stages and their columns per row (int64,
 * with a float to align them). */
#define NBUF 13
int64_t scatter_sweep_work(const struct nph_sweep *s)
{
    const int64_t st = stage_size(s);
    return s->ns * s->A * s->B + s->A * s->B + NBUF * s->A * s->B + s->B + st + (st ? 4 * s->A + 1 : 0);
}

/* Sweep bins [bin_lo, bin_hi) of the group ``s`` describes in ``work`` (scatter_sweep_work floats,
 * kept by the caller from call to call: fresh memory would cost a page fault per 4 KiB each time). */
CLONES
void scatter_sweep(const struct nph_sweep *s, int64_t bin_lo, int64_t bin_hi, float *work)
{
    const int64_t AB = s->A * s->B;
    float *planes = work, *buf = work + s->ns * AB + AB;
    struct rows rw;
    float **fields[NBUF] = {&rw.cur, &rw.em, &rw.r, &rw.rsum, &rw.etot, &rw.m1, &rw.mk, &rw.m2, &rw.md, &rw.pe,
                            &rw.ps, &rw.pk, &rw.pt};
    for (int f = 0; f < NBUF; f++)
        *fields[f] = buf + f * AB;
    rw.inrow = buf + NBUF * AB;
    const int64_t st = stage_size(s);
    float *stage = st ? rw.inrow + s->B : NULL;
    rw.cols = st ? (int64_t *)(((uintptr_t)(stage + st) + 7) & ~(uintptr_t)7) : NULL;
    unsigned csr = nph_flush_denormals();
    for (int64_t bin = bin_lo; bin < bin_hi; bin++)
        sweep_bin(s, bin, planes, planes + s->ns * AB, &rw, stage);
    nph_restore_denormals(csr);
}
