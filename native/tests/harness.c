/* Replays recorded kernel calls against the compiled library, on any platform it is built for.
 *
 *     harness --list              one line per kernel: name, return kind, argument kinds
 *     harness CALLS.bin OUT.bin   run the calls, write each call's result and buffers
 *
 * The kernels come from kernels.def (one line each), called through the library's exports.  CALLS.bin,
 * little-endian (tests/native/kernel_calls.py writes it from calls recorded on Linux):
 *
 *     "NPHCALL1" u32 ncalls, then per call:
 *       u32 len, name;  u32 nbuf, per buffer: u8 'b' u64 nbytes bytes | u8 't' u32 n, n words;
 *       u32 nargs, per argument: u8 'i' i64 | u8 'd' f64 | u8 'p' i32 buffer (-1: NULL)
 *
 * A 't' buffer is a table of 8-byte words, each u8 'i' i64 (an integer) or u8 'p' i32 buffer (-1: NULL;
 * a pointer to another buffer): a struct whose fields are all 8 bytes (pointers, int64_t), such as
 * scatter_sweep's struct nph_sweep or a struct of pointers.  An F32 argument is recorded as 'd' and
 * rounded to float here, as ctypes rounds a Python float.  OUT.bin: "NPHOUT01" u32 ncalls, per call:
 * i64 result (0 for void), u32 nbuf, per buffer u64 nbytes bytes (0 for a table).
 * Files are opened in binary mode: Windows would otherwise translate line ends.
 */

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "map.h"

union slot {
    int64_t I64;
    int32_t I32;
    double F64;
    void *P;
};

#define TYPE_I64 int64_t
#define TYPE_I32 int32_t
#define TYPE_F64 double
#define TYPE_F32 float
#define TYPE_P void *
#define TYPE_V void
#define NPH_CAT(a, b) NPH_CAT_(a, b)
#define NPH_CAT_(a, b) a##b
#define NPH_MAP(m, ...) NPH_CAT(NPH_MAP, NPH_NARGS(__VA_ARGS__))(m, 0, __VA_ARGS__)
#define PARAM(kind, i) TYPE_##kind
#define ARG(kind, i) ARG_##kind(i)
#define ARG_I64(i) a[i].I64
#define ARG_I32(i) a[i].I32
#define ARG_F64(i) a[i].F64
#define ARG_F32(i) (float)a[i].F64
#define ARG_P(i) a[i].P
#define STORE_V(call) (call, 0)
#define STORE_I64(call) (int64_t)(call)
#define STORE_I32(call) (int64_t)(call)

/* A declaration and a thunk per kernel: the thunk calls it with the slots' values. */
#define KERNEL(ret, name, ...)                                                                                        \
    TYPE_##ret name(NPH_MAP(PARAM, __VA_ARGS__));                                                                      \
    static int64_t run_##name(const union slot *a) { return STORE_##ret(name(NPH_MAP(ARG, __VA_ARGS__))); }
#include "kernels.def"
#undef KERNEL

struct kernel {
    const char *name, *ret, *args;
    int nargs;
    int64_t (*run)(const union slot *);
};

#define KERNEL(ret, name, ...) {#name, #ret, #__VA_ARGS__, NPH_NARGS(__VA_ARGS__), run_##name},
static const struct kernel KERNELS[] = {
#include "kernels.def"
};
#undef KERNEL
#define NKERNELS (sizeof KERNELS / sizeof KERNELS[0])

static FILE *in;

static void fail(const char *what)
{
    fprintf(stderr, "harness: %s\n", what);
    exit(2);
}

static void get(void *dst, size_t n)
{
    if (n && fread(dst, 1, n, in) != n)
        fail("CALLS file ends early");
}

#define GET(T) (get(&v_##T, sizeof v_##T), v_##T)
static uint8_t v_uint8_t;
static uint32_t v_uint32_t;
static int32_t v_int32_t;
static uint64_t v_uint64_t;
static int64_t v_int64_t;
static double v_double;

struct buffer {
    uint8_t kind;
    uint64_t nbytes;
    void *data;
    int32_t *refs; /* a table's buffer index per word (-1: NULL, -2: an integer word) */
};

static void run_call(FILE *out)
{
    char name[256];
    uint32_t len = GET(uint32_t);
    if (len >= sizeof name)
        fail("kernel name too long");
    get(name, len);
    name[len] = 0;
    const struct kernel *k = NULL;
    for (size_t i = 0; i < NKERNELS; i++)
        if (!strcmp(KERNELS[i].name, name))
            k = &KERNELS[i];
    if (!k) {
        fprintf(stderr, "harness: no entry for kernel %s in kernels.def\n", name);
        exit(3);
    }
    uint32_t nbuf = GET(uint32_t);
    struct buffer *buf = calloc(nbuf ? nbuf : 1, sizeof *buf);
    for (uint32_t b = 0; b < nbuf; b++) {
        buf[b].kind = GET(uint8_t);
        if (buf[b].kind == 'b') {
            buf[b].nbytes = GET(uint64_t);
            buf[b].data = malloc(buf[b].nbytes ? buf[b].nbytes : 1); /* malloc: 16-byte aligned */
            get(buf[b].data, buf[b].nbytes);
        } else if (buf[b].kind == 't') {
            uint32_t n = GET(uint32_t);
            buf[b].refs = malloc((n ? n : 1) * sizeof(int32_t));
            buf[b].data = calloc(n ? n : 1, sizeof(union slot)); /* 8 bytes: pointers and int64_t */
            buf[b].nbytes = n;
            for (uint32_t j = 0; j < n; j++) {
                uint8_t kind = GET(uint8_t);
                if (kind == 'p')
                    buf[b].refs[j] = GET(int32_t);
                else if (kind == 'i') {
                    buf[b].refs[j] = -2;
                    ((union slot *)buf[b].data)[j].I64 = GET(int64_t);
                } else
                    fail("unknown table word kind");
                if (buf[b].refs[j] >= (int32_t)nbuf)
                    fail("a table refers to a buffer the call lacks");
            }
        } else
            fail("unknown buffer kind");
    }
    for (uint32_t b = 0; b < nbuf; b++)
        for (uint64_t j = 0; buf[b].kind == 't' && j < buf[b].nbytes; j++)
            if (buf[b].refs[j] != -2)
                ((union slot *)buf[b].data)[j].P = buf[b].refs[j] < 0 ? NULL : buf[buf[b].refs[j]].data;
    uint32_t nargs = GET(uint32_t);
    if ((int)nargs != k->nargs) {
        fprintf(stderr, "harness: %s takes %d arguments in kernels.def, the call has %u\n", name, k->nargs, nargs);
        exit(3);
    }
    union slot a[64];
    for (uint32_t i = 0; i < nargs && i < 64; i++) {
        uint8_t kind = GET(uint8_t);
        if (kind == 'i') /* (an I32 argument reads the low half: little-endian) */
            a[i].I64 = GET(int64_t);
        else if (kind == 'd')
            a[i].F64 = GET(double);
        else if (kind == 'p') {
            int32_t b = GET(int32_t);
            a[i].P = b < 0 ? NULL : buf[b].data;
        } else
            fail("unknown argument kind");
    }
    int64_t r = k->run(a);
    fwrite(&r, sizeof r, 1, out);
    fwrite(&nbuf, sizeof nbuf, 1, out);
    for (uint32_t b = 0; b < nbuf; b++) {
        uint64_t n = buf[b].kind == 'b' ? buf[b].nbytes : 0;
        fwrite(&n, sizeof n, 1, out);
        fwrite(buf[b].data, 1, n, out);
        free(buf[b].data);
        free(buf[b].refs);
    }
    free(buf);
}

int main(int argc, char **argv)
{
    if (argc == 2 && !strcmp(argv[1], "--list")) {
        for (size_t i = 0; i < NKERNELS; i++)
            printf("%s %s %s\n", KERNELS[i].name, KERNELS[i].ret, KERNELS[i].args);
        return 0;
    }
    if (argc != 3)
        fail("usage: harness --list | harness CALLS.bin OUT.bin");
    char magic[8];
    if (!(in = fopen(argv[1], "rb")))
        fail("cannot open the CALLS file");
    get(magic, 8);
    if (memcmp(magic, "NPHCALL1", 8))
        fail("not a CALLS file");
    FILE *out = fopen(argv[2], "wb");
    if (!out)
        fail("cannot write the OUT file");
    uint32_t ncalls = GET(uint32_t);
    fwrite("NPHOUT01", 1, 8, out);
    fwrite(&ncalls, sizeof ncalls, 1, out);
    for (uint32_t c = 0; c < ncalls; c++)
        run_call(out);
    if (fclose(out))
        fail("writing the OUT file failed");
    fclose(in);
    return 0;
}
