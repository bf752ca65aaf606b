/* Node values of the blobby mesher's active blocks (nephele.core.muscle.blobby._node_values).
 *
 * Per (block, Gaussian) pair the exponent at node (k, j, i) of the block is
 * const + u.Ar - 1/2 u^T A u (u: the node's offset from the block's first node), split
 * into three 8x8 tables over (j, i), (k, i) and (k, j): 192 exponentials per pair, two
 * multiplies and an add per node.  The arithmetic is the NumPy twin's, operation by
 * operation (float64 tables rounded to float32, float32 products, summed in the block's
 * Gaussian order), so the two differ only in their float32 exp.  A block's values depend
 * on nothing but its own list: the same bits whichever blocks are asked for.
 */

#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
/* libm's vector variants (glibc's libmvec, x86-64): the vectorizer calls them for whole registers. */
float expf(float) __attribute__((simd("notinbranch")));
#define CLONES __attribute__((target_clones("avx2", "default")))
#else
#define CLONES
#endif

#define B 8
#define B2 (B * B)
#define B3 (B * B * B)
#define EXP_MAX 40.0f /* largest exponent of one float32 factor (_EXP_MAX) */

/* Per-call constants: node offsets u (per axis), u^2 / 2, and the float32 cross products. */
struct offsets {
    double u[3][B], hu[3][B];
    float uyx[B2], uzx[B2], uzy[B2];
};

static void offsets_init(struct offsets *o, const double *h)
{
    for (int a = 0; a < 3; a++)
        for (int n = 0; n < B; n++) {
            o->u[a][n] = n * h[a];
            o->hu[a][n] = 0.5 * (o->u[a][n] * o->u[a][n]);
        }
    for (int m = 0; m < B; m++)
        for (int n = 0; n < B; n++) {
            o->uyx[m * B + n] = (float)(o->u[1][m] * o->u[0][n]);
            o->uzx[m * B + n] = (float)(o->u[2][m] * o->u[0][n]);
            o->uzy[m * B + n] = (float)(o->u[2][m] * o->u[1][n]);
        }
}

/* The three exponent tables e = (eji, eki, ekj) of Gaussian g over the block with first node
 * at x0; returns whether one exceeds EXP_MAX (then the node values take the sum and one exp). */
static inline __attribute__((always_inline)) int tables(const double *c, const double *a6, double lnw, const double *x0,
                                                        const struct offsets *o, float *restrict e)
{
    double x = c[0] - x0[0], y = c[1] - x0[1], z = c[2] - x0[2];
    double ar0 = a6[0] * x + a6[3] * y + a6[4] * z;
    double ar1 = a6[3] * x + a6[1] * y + a6[5] * z;
    double ar2 = a6[4] * x + a6[5] * y + a6[2] * z;
    double cst = lnw - 0.5 * (x * ar0 + y * ar1 + z * ar2);
    float ai[B], bj[B], ck[B];
    for (int n = 0; n < B; n++) {
        ai[n] = (float)(o->u[0][n] * ar0 - o->hu[0][n] * a6[0]);
        bj[n] = (float)(o->u[1][n] * ar1 - o->hu[1][n] * a6[1] + cst);
        ck[n] = (float)(o->u[2][n] * ar2 - o->hu[2][n] * a6[2]);
    }
    float a3 = (float)a6[3], a4 = (float)a6[4], a5 = (float)a6[5];
    float mx[B] = {0};
    for (int m = 0; m < B; m++)
        for (int n = 0; n < B; n++) {
            float v1 = bj[m] + ai[n] - o->uyx[m * B + n] * a3;
            float v2 = -o->uzx[m * B + n] * a4;
            float v3 = ck[m] - o->uzy[m * B + n] * a5;
            e[m * B + n] = v1;
            e[B2 + m * B + n] = v2;
            e[2 * B2 + m * B + n] = v3;
            v1 = v1 > v2 ? v1 : v2;
            v1 = v1 > v3 ? v1 : v3;
            mx[n] = mx[n] > v1 ? mx[n] : v1;
        }
    int big = 0;
    for (int n = 0; n < B; n++)
        big |= mx[n] > EXP_MAX;
    return big;
}

/* A row of B floats, one register (two without AVX): the vectorizer would split it. */
typedef float row8 __attribute__((vector_size(B * sizeof(float))));

/* acc = (first ? 0 : acc) + the Gaussian's values from its exponent tables e (eji, eki, ekj). */
static inline __attribute__((always_inline)) void add_gaussian(float *restrict acc, float *restrict e, int big, int first)
{
    const float *eji = e, *eki = e + B2, *ekj = e + 2 * B2;
    if (big) {
        float p[B];
        for (int k = 0; k < B; k++)
            for (int j = 0; j < B; j++) {
                float *row = acc + (k * B + j) * B;
                for (int i = 0; i < B; i++)
                    p[i] = expf(ekj[k * B + j] + eki[k * B + i] + eji[j * B + i]);
                for (int i = 0; i < B; i++)
                    row[i] = first ? p[i] : row[i] + p[i];
            }
        return;
    }
    for (int n = 0; n < 3 * B2; n++)
        e[n] = expf(e[n]);
    for (int k = 0; k < B; k++) {
        row8 tki, tji, p, sum;
        memcpy(&tki, eki + k * B, sizeof tki);
        for (int j = 0; j < B; j++) {
            memcpy(&tji, eji + j * B, sizeof tji);
            p = ekj[k * B + j] * tki * tji;
            if (!first) {
                memcpy(&sum, acc + (k * B + j) * B, sizeof sum);
                p += sum;
            }
            memcpy(acc + (k * B + j) * B, &p, sizeof p);
        }
    }
}

/* out[b] (B^3 floats, (k, j, i) order) for the n blocks act[b]: the sum over the block's
 * Gaussians grid_g[grid_start[q] .. grid_start[q + 1]].  q: (na, 3) block coordinates,
 * c (m, 3), a6 (m, 6) inverse covariances (xx yy zz xy xz yz), lnw (m,) log weights,
 * h the node spacing and size the block size per axis. */
CLONES
void blobby_node_values(int64_t n, const int64_t *act, const int64_t *grid_start, const int64_t *grid_g,
                        const int64_t *q, const double *c, const double *a6, const double *lnw,
                        const double *h, const double *size, float *out)
{
    struct offsets o;
    offsets_init(&o, h);
    float e[3 * B2];
    for (int64_t b = 0; b < n; b++) {
        int64_t blk = act[b];
        float *acc = out + b * B3;
        double x0[3] = {q[3 * blk] * size[0], q[3 * blk + 1] * size[1], q[3 * blk + 2] * size[2]};
        if (grid_start[blk] == grid_start[blk + 1])
            for (int n3 = 0; n3 < B3; n3++)
                acc[n3] = 0.0f;
        for (int64_t p = grid_start[blk]; p < grid_start[blk + 1]; p++) {
            int64_t g = grid_g[p];
            int big = tables(c + 3 * g, a6 + 6 * g, lnw[g], x0, &o, e);
            add_gaussian(acc, e, big, p == grid_start[blk]);
        }
    }
}
