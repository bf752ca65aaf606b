/* Marching cubes over a run of the blobby mesher's blocks (nephele.core.muscle.blobby._march).
 *
 * Per block: the (B+1)^3 extended nodes (its own values and its +1 neighbours'), the node
 * signs as bit sets, whence the cut edges in slot order (axis, k, j, i) and the cut cells
 * (only they are visited: some 50 edges and 100 cells of 2187 and 512), emitted
 * as the NumPy twin's _Chunk arrays in its order: owned vertices, then the run's duplicate
 * vertices (ghost edges no active block owns), references of ghost edges, triangles cell by
 * cell.  Two calls per run: blobby_march_count fills the extended nodes and counts what
 * blobby_march_emit then writes into arrays of those sizes.  The float arithmetic (edge
 * parameters, the cubic's Newton step) is the twin's, operation by operation.
 */

#include <math.h>
#include <stdint.h>
#include <string.h>

#define B 8
#define E (B + 1)
#define E2 (E * E)
#define E3 (E * E * E)

/* Inputs, in this order (Python passes an array of their addresses). */
struct march_in {
    const int64_t *bl;         /* (n,) active blocks, ascending */
    const float *values;       /* (rows, B^3) node values */
    const int64_t *loc;        /* (na,) row of each block in values, or NULL: row = block */
    const int64_t *nbr;        /* (na, 8) neighbour at offset code 4 dz + 2 dy + dx; -1 below, -2 above */
    const int64_t *q;          /* (na, 3) block coordinates */
    const int64_t *box_nb;     /* (3,) blocks per axis of a periodic grid, or NULL */
    const int64_t *node_lo;    /* (3,) lowest node of the edge key's range */
    const int64_t *node_dims;  /* (3,) its nodes per axis */
    const int32_t *table;      /* (256, 5, 3) triangle corners' edge slot offsets */
    const int64_t *ntri;       /* (256,) triangles per configuration */
    const int8_t *kind;        /* (3 E^3,) 0 no edge, 1 owned, 2 owned by a neighbour */
    const int64_t *face_index; /* (3 E^3,) owned lower-face slot -> face store index, or -1 */
    float *ext;                /* (n, E^3) scratch: the extended nodes (count writes, emit reads) */
};

/* Outputs (the _Chunk fields), sized from the counts. */
struct march_out {
    int32_t *blk;
    int8_t *axis;
    uint8_t *node;
    double *t;
    float *curv;
    uint8_t *a_above;
    int32_t *faces;
    int32_t *ref_owner;
    int32_t *ref_slot;
    int8_t *ref_shift;
    int64_t *dup_key;
    int64_t *dup_shift;
    int64_t *face_key;
    int32_t *face_vid;
};

enum { N_OWN, N_GHOST, N_DUP, N_TRI, N_FACE, N_COUNTS };

static const int STRIDE[3] = {1, E, E2};

static const float *row(const struct march_in *in, int64_t blk)
{
    return in->values + (in->loc ? in->loc[blk] : blk) * (B * B * B);
}

/* The block's extended nodes: its own, then the +1 layers from its neighbours (an inactive
 * one's nodes are 2 level above or 0 below: only their side counts). */
static void extend(const struct march_in *in, int64_t blk, float lvl, float *ext)
{
    const float *v = row(in, blk);
    for (int k = 0; k < B; k++)
        for (int j = 0; j < B; j++)
            memcpy(ext + (k * E + j) * E, v + (k * B + j) * B, B * sizeof(float));
    for (int code = 1; code < 8; code++) {
        int dx = code & 1, dy = (code >> 1) & 1, dz = code >> 2;
        int64_t nb = in->nbr[8 * blk + code];
        const float *src = nb >= 0 ? row(in, nb) : NULL;
        float guess = nb == -2 ? 2.0f * lvl : 0.0f;
        for (int k = dz ? B : 0; k < (dz ? E : B); k++)
            for (int j = dy ? B : 0; j < (dy ? E : B); j++)
                for (int i = dx ? B : 0; i < (dx ? E : B); i++)
                    ext[(k * E + j) * E + i] = src ? src[((dz ? 0 : k) * B + (dy ? 0 : j)) * B + (dx ? 0 : i)] : guess;
    }
}

/* The linear edge parameter, clipped to [margin, 1 - margin] (0.5 where undefined). */
static double linear_t(double level, float va, float vz, double margin)
{
    double t = (level - (double)va) / ((double)vz - (double)va);
    if (!__builtin_isfinite(t)) /* MinGW-w64's isfinite calls __fpclassify, which the UCRT lacks */
        t = 0.5;
    return t < margin ? margin : (t > 1 - margin ? 1 - margin : t);
}

/* _edge_guess for one vertex: one Newton step on the cubic (or quadratic) through the node
 * values along the edge; *curv its second derivative there, or NaN where not usable. */
static double edge_guess(const float *ext, int at, int axis, int coord, int beyond_real, double level, double t,
                         double margin, float *curv)
{
    float lo = (float)margin, hi = (float)(1 - margin);
    int s = STRIDE[axis];
    int up1 = (coord + 1 < B) | beyond_real;
    int has_m = coord >= 1;
    int has_p2 = (coord + 2 < B) | ((coord + 2 == B) & beyond_real);
    int ok = up1 & (has_m | has_p2);
    float fm = ext[has_m ? at - s : at], f0 = ext[at], f1 = ext[at + s], f2 = ext[has_p2 ? at + 2 * s : at];
    float c0 = f0 - (float)level;
    float c2 = has_m ? 0.5f * (fm + f1) - f0 : 0.5f * (f0 + f2) - f1;
    float c3 = has_m & has_p2 ? (f2 - fm) / 6.0f + 0.5f * (f0 - f1) : 0.0f;
    float c1 = f1 - f0 - c2 - c3;
    float t0 = (float)t;
    float dp = c1 + t0 * (2 * c2 + 3 * t0 * c3);
    float t1 = t0 - (c0 + t0 * (c1 + t0 * (c2 + t0 * c3))) / dp;
    t1 = t1 < lo ? lo : (t1 > hi ? hi : t1);
    ok &= dp * (f1 - f0) > 0;
    *curv = ok ? 2 * c2 + 6 * t1 * c3 : NAN;
    return ok ? t1 : t;
}

/* Edge key of grid edge (axis, node) (_edge_key), the node wrapped into a periodic grid. */
static int64_t edge_key(const struct march_in *in, const int64_t *node, int axis)
{
    int64_t n[3];
    for (int a = 0; a < 3; a++) {
        n[a] = node[a];
        if (in->box_nb) {
            int64_t m = B * in->box_nb[a];
            n[a] = ((n[a] % m) + m) % m;
        }
        n[a] -= in->node_lo[a];
    }
    return ((axis * in->node_dims[2] + n[2]) * in->node_dims[1] + n[1]) * in->node_dims[0] + n[0];
}

/* Vertex v's arrays but t and curv: the edge (axis, lower node ijk) of block blk, at ext[at]. */
static void put_vertex(struct march_out *out, int64_t v, int64_t blk, int axis, const int *ijk, const float *ext, int at,
                       float lvl)
{
    out->blk[v] = (int32_t)blk;
    out->axis[v] = (int8_t)axis;
    for (int a = 0; a < 3; a++)
        out->node[3 * v + a] = (uint8_t)ijk[a];
    out->a_above[v] = ext[at] >= lvl;
}

/* Bit sets over a block's E^3 extended nodes, bit p for node p = (k E + j) E + i. */
#define W ((E3 + 63) / 64)

/* out = in >> d: bit p of out is bit p + d of in (0 past the end). */
static void shr(uint64_t *out, const uint64_t *in, int d)
{
    int q = d / 64, r = d % 64;
    for (int w = 0; w < W; w++) {
        uint64_t lo = w + q < W ? in[w + q] : 0, hi = w + q + 1 < W ? in[w + q + 1] : 0;
        out[w] = r ? lo >> r | hi << (64 - r) : lo;
    }
}

/* Edge slots by kind (per axis: owned, owned by a neighbour, owned on a lower face) and the
 * nodes that are a cell's lower corner in the block (k, j, i < B). */
struct masks {
    uint64_t own[3][W], ghost[3][W], face[3][W], cell[W];
};

static void masks_init(struct masks *m, const struct march_in *in)
{
    memset(m, 0, sizeof *m);
    for (int a = 0; a < 3; a++)
        for (int p = 0; p < E3; p++) {
            uint64_t bit = (uint64_t)1 << (p % 64);
            int kind = in->kind[a * E3 + p];
            m->own[a][p / 64] |= kind == 1 ? bit : 0;
            m->ghost[a][p / 64] |= kind == 2 ? bit : 0;
            m->face[a][p / 64] |= kind == 1 && in->face_index[a * E3 + p] >= 0 ? bit : 0;
        }
    for (int p = 0; p < E3; p++)
        m->cell[p / 64] |= (uint64_t)(p % E < B && (p / E) % E < B && p / E2 < B) << (p % 64);
}

/* Emit one owned vertex (edge slot, lower node p). */
static void owned_vertex(const struct march_in *in, struct march_out *out, int64_t blk, const float *ext, int axis,
                         int p, double level, double margin, int64_t v)
{
    int ijk[3] = {p % E, (p / E) % E, p / E2}, d = STRIDE[axis];
    put_vertex(out, v, blk, axis, ijk, ext, p, (float)level);
    int beyond = in->nbr[8 * blk + (1 << axis)] >= 0;
    double t = linear_t(level, ext[p], ext[p + d], margin);
    out->t[v] = edge_guess(ext, p, axis, ijk[axis], beyond, level, t, margin, &out->curv[v]);
}

/* A ghost edge (reference r): its owner's face slot, or (owner inactive) a duplicate vertex of
 * our own.  Emits where out is not NULL; returns whether it is a duplicate. */
static int ghost_edge(const struct march_in *in, struct march_out *out, int64_t blk, const float *ext, int axis, int p,
                      double level, double margin, int64_t n_own, int64_t r, int64_t dup)
{
    int ijk[3] = {p % E, (p / E) % E, p / E2};
    int64_t owner = in->nbr[8 * blk + 4 * (ijk[2] == B) + 2 * (ijk[1] == B) + (ijk[0] == B)];
    if (!out)
        return owner < 0;
    int64_t node[3];
    for (int a = 0; a < 3; a++) {
        int8_t shift = in->box_nb ? in->q[3 * blk + a] + (ijk[a] == B) >= in->box_nb[a] : 0;
        out->ref_shift[3 * r + a] = shift;
        if (owner < 0)
            out->dup_shift[3 * dup + a] = shift;
        node[a] = in->q[3 * blk + a] * B + ijk[a];
    }
    out->ref_owner[r] = owner < 0 ? -1 : (int32_t)owner;
    if (owner >= 0) {
        out->ref_slot[r] = (int32_t)in->face_index[((axis * E + ijk[2] % B) * E + ijk[1] % B) * E + ijk[0] % B];
        return 0;
    }
    int64_t v = n_own + dup;
    out->ref_slot[r] = (int32_t)v;
    out->dup_key[dup] = edge_key(in, node, axis);
    put_vertex(out, v, blk, axis, ijk, ext, p, (float)level);
    out->t[v] = linear_t(level, ext[p], ext[p + STRIDE[axis]], margin);
    out->curv[v] = NAN;
    return 1;
}

/* Count (out NULL) or emit one block's cut edges in slot order (axis, node); c: running
 * counts; lut: edge slot -> vertex (>= 0) or reference (-1 - r).  n_own: the run's owned
 * vertices (duplicates come after them). */
static void edges(const struct march_in *in, struct march_out *out, const struct masks *m, int64_t b, double level,
                  double margin, int64_t nslots, int64_t n_own, uint64_t cut[3][W], int32_t *lut, int64_t *c)
{
    int64_t blk = in->bl[b];
    const float *ext = in->ext + b * E3;
    for (int a = 0; a < 3; a++)
        for (int w = 0; w < W; w++) {
            uint64_t own = cut[a][w] & m->own[a][w], ghost = cut[a][w] & m->ghost[a][w];
            if (!out) {
                c[N_OWN] += __builtin_popcountll(own);
                c[N_FACE] += __builtin_popcountll(own & m->face[a][w]);
                c[N_GHOST] += __builtin_popcountll(ghost);
                for (; ghost; ghost &= ghost - 1)
                    c[N_DUP] += ghost_edge(in, NULL, blk, ext, a, 64 * w + __builtin_ctzll(ghost), level, margin, 0, 0, 0);
                continue;
            }
            for (uint64_t x = own | ghost; x; x &= x - 1) {
                int p = 64 * w + __builtin_ctzll(x), slot = a * E3 + p;
                if (own >> (p % 64) & 1) {
                    int64_t v = c[N_OWN]++;
                    if (m->face[a][w] >> (p % 64) & 1) {
                        out->face_key[c[N_FACE]] = blk * nslots + in->face_index[slot];
                        out->face_vid[c[N_FACE]++] = (int32_t)v;
                    }
                    lut[slot] = (int32_t)v;
                    owned_vertex(in, out, blk, ext, a, p, level, margin, v);
                } else {
                    int64_t r = c[N_GHOST]++;
                    lut[slot] = (int32_t)(-1 - r);
                    c[N_DUP] += ghost_edge(in, out, blk, ext, a, p, level, margin, n_own, r, c[N_DUP]);
                }
            }
        }
}

/* Count (out NULL) or emit the triangles of the block's cells (k, j, i order) in live. */
static void cells(const struct march_in *in, struct march_out *out, const uint8_t *s, const uint64_t *live,
                  const int32_t *lut, int64_t *c)
{
    for (int w = 0; w < W; w++)
        for (uint64_t x = live[w]; x; x &= x - 1) {
            int p = 64 * w + __builtin_ctzll(x);
            int cfg = s[p] | s[p + 1] << 1 | s[p + E] << 2 | s[p + E + 1] << 3 | s[p + E2] << 4 | s[p + E2 + 1] << 5 |
                      s[p + E2 + E] << 6 | s[p + E2 + E + 1] << 7;
            int64_t nt = in->ntri[cfg];
            for (int64_t t = 0; out && t < nt; t++)
                for (int k = 0; k < 3; k++)
                    out->faces[3 * (c[N_TRI] + t) + k] = lut[in->table[(cfg * 5 + t) * 3 + k] + p];
            c[N_TRI] += nt;
        }
}

/* The block's node signs, cut edges and cut cells, then its edges and cells. */
static void march_block(const struct march_in *in, struct march_out *out, const struct masks *m, int64_t b,
                        double level, double margin, int64_t nslots, int64_t n_own, int64_t *c)
{
    const float *ext = in->ext + b * E3;
    float lvl = (float)level;
    uint8_t s[64 * W] = {0};
    for (int p = 0; p < E3; p++)
        s[p] = ext[p] >= lvl;
    uint64_t sign[W], cut[3][W], x[W], live[W];
    for (int w = 0; w < W; w++) {
        sign[w] = 0;
        for (int g = 0; g < 8; g++) { /* 8 bytes of 0 or 1 -> 8 bits */
            uint64_t v;
            memcpy(&v, s + 64 * w + 8 * g, 8);
            sign[w] |= (v * 0x0102040810204080u) >> 56 << (8 * g);
        }
    }
    for (int a = 0; a < 3; a++) {
        shr(x, sign, STRIDE[a]);
        for (int w = 0; w < W; w++)
            cut[a][w] = sign[w] ^ x[w];
    }
    /* A cell is cut if one of 7 of its edges is (they join its 8 corners): x at (0, 0), (1, 0),
     * (0, 1), (1, 1) in (y, z), y at z = 0, 1, z at (0, 0). */
    memcpy(live, cut[0], sizeof live);
    static const int XS[3] = {E, E2, E + E2};
    for (int n = 0; n < 3; n++) {
        shr(x, cut[0], XS[n]);
        for (int w = 0; w < W; w++)
            live[w] |= x[w];
    }
    shr(x, cut[1], E2);
    for (int w = 0; w < W; w++)
        live[w] = (live[w] | x[w] | cut[1][w] | cut[2][w]) & m->cell[w];
    int32_t lut[3 * E3];
    edges(in, out, m, b, level, margin, nslots, n_own, cut, lut, c);
    cells(in, out, s, live, lut, c);
}

/* Fill the n blocks' extended nodes (in->ext) and count: counts[] = owned vertices, ghost edges,
 * duplicate vertices, triangles, owned vertices on a lower face. */
void blobby_march_count(int64_t n, double level, const struct march_in *in, int64_t *counts)
{
    for (int a = 0; a < N_COUNTS; a++)
        counts[a] = 0;
    struct masks m;
    masks_init(&m, in);
    for (int64_t b = 0; b < n; b++) {
        extend(in, in->bl[b], (float)level, in->ext + b * E3);
        march_block(in, NULL, &m, b, level, 0.0, 0, 0, counts);
    }
}

/* Write the run's _Chunk arrays (sized from blobby_march_count's counts). */
void blobby_march_emit(int64_t n, double level, double margin, int64_t nslots, const struct march_in *in,
                       const int64_t *counts, struct march_out *out)
{
    int64_t c[N_COUNTS] = {0};
    struct masks m;
    masks_init(&m, in);
    for (int64_t b = 0; b < n; b++)
        march_block(in, out, &m, b, level, margin, nslots, counts[N_OWN], c);
}
