/* The blobby mesher's block search (nephele.core.muscle.blobby._block_pairs and _find_blocks):
 * which blocks each Gaussian may reach, with bounds of it over them, and the pairs grouped by
 * active block.  The arithmetic is the NumPy twins', but exp is fastexp.h's (libm's exp would
 * tie the wheel to glibc 2.29's symbol version; Blender runs on 2.28).
 */

#include <math.h>
#include <stdint.h>

#include "fastexp.h"

/* The block search (_block_pairs): for Gaussians g0 .. g1 - 1, every block of its candidate
 * box lo[g] .. lo[g] + cnt[g] - 1 (z, y, x order) whose closed box may meet the Gaussian's
 * cut_fine ellipsoid: its index key, the Gaussian, whether it meets the cut ellipsoid too
 * (on_grid), and then bounds of the Gaussian over the block from above and below (else 0).
 * ra[g]: the largest A-norm of a block's half-diagonals.  The arithmetic is the NumPy twin's.
 * Returns the number of pairs written. */
int64_t blobby_block_pairs(int64_t g0, int64_t g1, const int64_t *lo, const int64_t *cnt, const double *c,
                           const double *a6, const double *lnw, const double *smax, const double *ra, const double *size,
                           double cut, double cut_fine, const int64_t *index_lo, const int64_t *index_dims,
                           int64_t periodic, int64_t *key, int64_t *gout, uint8_t *on_grid, double *upper,
                           double *lower)
{
    int64_t n = 0;
    for (int64_t g = g0; g < g1; g++) {
        const int64_t *l = lo + 3 * g, *ct = cnt + 3 * g;
        const double *a = a6 + 6 * g;
        double w = nph_exp(lnw[g]);
        for (int64_t z = 0; z < ct[2]; z++)
            for (int64_t y = 0; y < ct[1]; y++)
                for (int64_t x = 0; x < ct[0]; x++) {
                    int64_t q[3] = {l[0] + x, l[1] + y, l[2] + z};
                    double d[3], gap[3];
                    for (int k = 0; k < 3; k++) {
                        d[k] = ((double)q[k] + 0.5) * size[k] - c[3 * g + k];
                        gap[k] = fmax(fabs(d[k]) - size[k] / 2, 0.0);
                    }
                    double sq = sqrt(a[0] * d[0] * d[0] + a[1] * d[1] * d[1] + a[2] * d[2] * d[2] +
                                     2 * (a[3] * d[0] * d[1] + a[4] * d[0] * d[2] + a[5] * d[1] * d[2]));
                    double gn = sqrt(gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]);
                    double near = fmax(fmax(sq - ra[g], 0.0), gn / smax[g]);
                    if (!(near <= cut_fine))
                        continue;
                    double far = sq + ra[g];
                    int on = near <= cut;
                    int64_t r[3];
                    for (int k = 0; k < 3; k++) {
                        r[k] = q[k] - index_lo[k];
                        if (periodic)
                            r[k] = (r[k] % index_dims[k] + index_dims[k]) % index_dims[k];
                    }
                    key[n] = (r[2] * index_dims[1] + r[1]) * index_dims[0] + r[0];
                    gout[n] = g;
                    on_grid[n] = (uint8_t)on;
                    upper[n] = on ? w * nph_exp(-0.5 * (near * near)) : 0.0;
                    lower[n] = on ? w * nph_exp(-0.5 * (far * far)) : 0.0;
                    n++;
                }
    }
    return n;
}

/* Grouping the kept pairs by active block (_find_blocks), pair p's block being a = cls[slot[p]]
 * (< 0: not active).  Counting: fine_start and grid_start (na + 1) of the lists of every pair
 * and of the on-grid ones. */
void blobby_group_count(int64_t npairs, const int64_t *slot, const int64_t *cls, const uint8_t *on_grid, int64_t na,
                        int64_t *fine_start, int64_t *grid_start)
{
    for (int64_t a = 0; a <= na; a++)
        fine_start[a] = grid_start[a] = 0;
    for (int64_t p = 0; p < npairs; p++) {
        int64_t a = cls[slot[p]];
        if (a >= 0) {
            fine_start[a + 1]++;
            grid_start[a + 1] += on_grid[p];
        }
    }
    for (int64_t a = 0; a < na; a++) {
        fine_start[a + 1] += fine_start[a];
        grid_start[a + 1] += grid_start[a];
    }
}

/* Filling, in pair order (a stable sort by block): the Gaussians g of each block's pairs into
 * fine_g and of its on-grid ones into grid_g, and first[a] the block's first pair.  cursor:
 * scratch of 2 na. */
void blobby_group_fill(int64_t npairs, const int64_t *slot, const int64_t *cls, const uint8_t *on_grid, const int64_t *g,
                       int64_t na, const int64_t *fine_start, const int64_t *grid_start, int64_t *fine_g,
                       int64_t *grid_g, int64_t *first, int64_t *cursor)
{
    int64_t *fc = cursor, *gc = cursor + na;
    for (int64_t a = 0; a < na; a++) {
        fc[a] = fine_start[a];
        gc[a] = grid_start[a];
    }
    for (int64_t p = 0; p < npairs; p++) {
        int64_t a = cls[slot[p]];
        if (a < 0)
            continue;
        if (fc[a] == fine_start[a])
            first[a] = p;
        fine_g[fc[a]++] = g[p];
        if (on_grid[p])
            grid_g[gc[a]++] = g[p];
    }
}
