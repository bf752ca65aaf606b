/* NPH_INLINE: the headers' small math helpers are always inlined.  A call inside a kernel's loop
 * leaves that loop scalar, and GCC's inlining budget, which moves with unrelated code, once left
 * nph_expf a call in the second-moment rows (4x slower than their vector twins). */

#ifndef NEPHELE_NPH_INLINE_H
#define NEPHELE_NPH_INLINE_H

#if defined(__GNUC__) || defined(__clang__)
#define NPH_INLINE static inline __attribute__((always_inline))
#else
#define NPH_INLINE static inline
#endif

#endif
