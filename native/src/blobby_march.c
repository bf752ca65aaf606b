/* Marching cubes over a run of the blobby mesher's blocks (nephele.core.muscle.blobby._march).
 *
 * Per block: the (B+1)^3 extended nodes (its own values and its +1 neighbours'), the node
 * signs, the cut edges in slot order (axis, k, j, i) and the cells' configurations, emitted
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
    if (!isfinite(t))
        t = 0.5;
    return t < margin ? margin : (t > 1 - margin ? 1 - margin : t);
}

/* _edge_guess for one vertex: one Newton step on the cubic (or quadratic) through the node
 * values along the edge; *curv its second derivative there, or NaN where not usable. */
static double edge_guess(const float *ext, int at, int axis, int coord, int beyond_real, double level, double t,
                         float margin, float *curv)
{
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
    t1 = t1 < margin ? margin : (t1 > 1 - margin ? 1 - margin : t1);
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

/* A run of bytes' positions that may be nonzero: whole 8-byte words of zeros are skipped. */
static int next_set(const uint8_t *x, int p, int end)
{
    while (p < end && !x[p]) {
        uint64_t w;
        if (p % 8 == 0 && p + 8 <= end && (memcpy(&w, x + p, 8), w == 0))
            p += 8;
        else
            p++;
    }
    return p;
}

/* Count (out NULL) or emit one block's cut edges (cut: slot -> its kind where cut, else 0);
 * c: running counts; lut: edge slot -> vertex (>= 0) or reference (-1 - r).  n_own: the run's
 * owned vertices (duplicates come after them). */
static void edges(const struct march_in *in, struct march_out *out, int64_t b, double level, double margin,
                  int64_t nslots, int64_t n_own, const uint8_t *cut, int32_t *lut, int64_t *c)
{
    float lvl = (float)level;
    int64_t blk = in->bl[b];
    const float *ext = in->ext + b * E3;
    for (int slot = next_set(cut, 0, 3 * E3); slot < 3 * E3; slot = next_set(cut, slot + 1, 3 * E3)) {
        int axis = slot / E3, p = slot % E3, d = STRIDE[axis];
        int ijk[3] = {p % E, (p / E) % E, p / E2};
        if (cut[slot] == 1) {
            int64_t v = c[N_OWN]++, fi = in->face_index[slot];
            if (fi >= 0 && out) {
                out->face_key[c[N_FACE]] = blk * nslots + fi;
                out->face_vid[c[N_FACE]] = (int32_t)v;
            }
            c[N_FACE] += fi >= 0;
            if (!out)
                continue;
            lut[slot] = (int32_t)v;
            put_vertex(out, v, blk, axis, ijk, ext, p, lvl);
            int beyond = in->nbr[8 * blk + (1 << axis)] >= 0;
            double t = linear_t(level, ext[p], ext[p + d], margin);
            out->t[v] = edge_guess(ext, p, axis, ijk[axis], beyond, level, t, (float)margin, &out->curv[v]);
            continue;
        }
        /* A ghost edge: its owner's face slot, or (owner inactive) a duplicate vertex of our own. */
        int64_t r = c[N_GHOST]++;
        int64_t owner = in->nbr[8 * blk + 4 * (ijk[2] == B) + 2 * (ijk[1] == B) + (ijk[0] == B)];
        int64_t dup = owner < 0 ? c[N_DUP]++ : -1;
        if (!out)
            continue;
        lut[slot] = (int32_t)(-1 - r);
        int64_t node[3];
        for (int a = 0; a < 3; a++) {
            int8_t shift = in->box_nb ? in->q[3 * blk + a] + (ijk[a] == B) >= in->box_nb[a] : 0;
            out->ref_shift[3 * r + a] = shift;
            if (dup >= 0)
                out->dup_shift[3 * dup + a] = shift;
            node[a] = in->q[3 * blk + a] * B + ijk[a];
        }
        out->ref_owner[r] = owner < 0 ? -1 : (int32_t)owner;
        if (owner >= 0) {
            out->ref_slot[r] = (int32_t)in->face_index[((axis * E + ijk[2] % B) * E + ijk[1] % B) * E + ijk[0] % B];
            continue;
        }
        int64_t v = n_own + dup;
        out->ref_slot[r] = (int32_t)v;
        out->dup_key[dup] = edge_key(in, node, axis);
        put_vertex(out, v, blk, axis, ijk, ext, p, lvl);
        out->t[v] = linear_t(level, ext[p], ext[p + d], margin);
        out->curv[v] = NAN;
    }
}

/* Count (out NULL) or emit one block's triangles, cell by cell (k, j, i); cfg: each node's
 * cell configuration, live: nonzero where the cell is in the block and cut. */
static void cells(const struct march_in *in, struct march_out *out, const uint8_t *cfg, const uint8_t *live,
                  const int32_t *lut, int64_t *c)
{
    for (int p = next_set(live, 0, E3); p < E3; p = next_set(live, p + 1, E3)) {
        int64_t nt = in->ntri[cfg[p]];
        for (int64_t t = 0; out && t < nt; t++)
            for (int m = 0; m < 3; m++)
                out->faces[3 * (c[N_TRI] + t) + m] = lut[in->table[(cfg[p] * 5 + t) * 3 + m] + p];
        c[N_TRI] += nt;
    }
}

/* The block's node signs, cut edges and cell configurations, then its edges and cells. */
static void march_block(const struct march_in *in, struct march_out *out, int64_t b, double level, double margin,
                        int64_t nslots, int64_t n_own, const uint8_t *cell_in_block, int64_t *c)
{
    const float *ext = in->ext + b * E3;
    float lvl = (float)level;
    uint8_t s[E3 + E2 + E + 1] = {0}; /* node signs, zero-padded for the whole-array shifts below */
    for (int p = 0; p < E3; p++)
        s[p] = ext[p] >= lvl;
    uint8_t cut[3 * E3], cfg[E3], live[E3];
    for (int axis = 0; axis < 3; axis++)
        for (int p = 0; p < E3; p++)
            cut[axis * E3 + p] = in->kind[axis * E3 + p] & -(s[p] ^ s[p + STRIDE[axis]]);
    for (int p = 0; p < E3; p++) {
        cfg[p] = s[p] | s[p + 1] << 1 | s[p + E] << 2 | s[p + E + 1] << 3 | s[p + E2] << 4 | s[p + E2 + 1] << 5 |
                 s[p + E2 + E] << 6 | s[p + E2 + E + 1] << 7;
        live[p] = cell_in_block[p] & ((uint8_t)(cfg[p] + 1) > 1); /* not all below (0) or all above (255) */
    }
    int32_t lut[3 * E3];
    edges(in, out, b, level, margin, nslots, n_own, cut, lut, c);
    cells(in, out, cfg, live, lut, c);
}

/* 1 at the nodes that are a cell's lower corner in the block (k, j, i < B). */
static void cells_in_block(uint8_t *x)
{
    for (int p = 0; p < E3; p++)
        x[p] = p % E < B && (p / E) % E < B && p / E2 < B;
}

/* Fill the n blocks' extended nodes (in->ext) and count: counts[] = owned vertices, ghost edges,
 * duplicate vertices, triangles, owned vertices on a lower face. */
void blobby_march_count(int64_t n, double level, const struct march_in *in, int64_t *counts)
{
    for (int a = 0; a < N_COUNTS; a++)
        counts[a] = 0;
    uint8_t in_block[E3];
    cells_in_block(in_block);
    for (int64_t b = 0; b < n; b++) {
        extend(in, in->bl[b], (float)level, in->ext + b * E3);
        march_block(in, NULL, b, level, 0.0, 0, 0, in_block, counts);
    }
}

/* Write the run's _Chunk arrays (sized from blobby_march_count's counts). */
void blobby_march_emit(int64_t n, double level, double margin, int64_t nslots, const struct march_in *in,
                       const int64_t *counts, struct march_out *out)
{
    int64_t c[N_COUNTS] = {0};
    uint8_t in_block[E3];
    cells_in_block(in_block);
    for (int64_t b = 0; b < n; b++)
        march_block(in, out, b, level, margin, nslots, counts[N_OWN], in_block, c);
}
