// The tile kernels' vector layer in GCC's generic vectors and builtins only: no intrinsics, so
// kernels.h builds for any CPU GCC targets (RASTER_PORTABLE: NEON on aarch64; on x86 the same
// code is a third, selectable variant, which tests its numerics natively).
//
// Included by kernels.h inside its namespace, in place of the AVX-512 and AVX2 layers, and
// defines what they define: the row types vf / vi, their operators and conversions (written
// part-wise in vec_split.h, shared with the AVX2 layer), selects, lane masks, lane sums, fused
// multiply-adds, sqrt / ceil / floor and the reciprocal's estimate.
//
// A tile row (16 floats) is four 16-byte quarters, each a generic vector of the width every
// SIMD target has (one q register on NEON, one xmm on x86), with each operation written
// quarter-wise, as the AVX2 layer does with its two ymm halves. One 64-byte generic vector per
// row would be shorter, but GCC lowers its comparisons and selects lane by lane on targets with
// narrower registers (seen on aarch64: scalar fcmp / fcsel per lane, values through the stack).
#pragma once

// Quarters per tile row.
constexpr int kQuarters = 4;
typedef float qf __attribute__((vector_size(16), __may_alias__));
typedef int32_t qi __attribute__((vector_size(16), __may_alias__));
constexpr int kParts = kQuarters;  // vec_split.h: the row types, their operators and conversions
typedef qf pf;
typedef qi pi;
#include "vec_split.h"

static inline vf vsel(vi m, vf a, vf b) { RASTER_PARTWISE(vf, m.h[k] ? a.h[k] : b.h[k]); }
static inline vi vseli(vi m, vi a, vi b) { RASTER_PARTWISE(vi, m.h[k] ? a.h[k] : b.h[k]); }

// Bit i set when lane i of the mask (0 or -1 per lane) is set: each lane keeps its own bit of
// its quarter, and the quarter's four bits are disjoint, so their sum is their union.
static inline uint32_t movemask(vi m) {
  const qi bit = {1, 2, 4, 8};
  uint32_t bits = 0;
  for (int k = 0; k < kQuarters; ++k) {
    const qi b = m.h[k] & bit;
    bits |= (uint32_t)(b[0] + b[1] + b[2] + b[3]) << (4 * k);
  }
  return bits;
}

// Sum of the 4 lanes of a quarter: pairs, then their sum (the order of the x86 hsum8's tail).
static inline float hsum4q(qf s) {
  const qf p = s + __builtin_shufflevector(s, s, 2, 3, 0, 1);
  return p[0] + p[1];
}

static inline float hsum(vf v) { return hsum4q((v.h[0] + v.h[2]) + (v.h[1] + v.h[3])); }

// out[s] += sum of the lanes of v[s] for s < n (n <= 16): as the x86 add_lane_sums, the
// quarters are added first, then a transposing tree over groups of four vectors (one quarter
// each: lane i of the result is the sum of the group's vector i).
static inline void add_lane_sums(const vf* v, int n, float* out) {
  for (int base = 0; base < n; base += 4) {
    qf x[4];
    for (int i = 0; i < 4; ++i)
      x[i] = base + i < n ? (v[base + i].h[0] + v[base + i].h[2]) +
                                (v[base + i].h[1] + v[base + i].h[3])
                          : qf{};
    const qf p0 = __builtin_shufflevector(x[0], x[1], 0, 1, 4, 5) +
                  __builtin_shufflevector(x[0], x[1], 2, 3, 6, 7);
    const qf p1 = __builtin_shufflevector(x[2], x[3], 0, 1, 4, 5) +
                  __builtin_shufflevector(x[2], x[3], 2, 3, 6, 7);
    const qf sums = __builtin_shufflevector(p0, p1, 0, 2, 4, 6) +
                    __builtin_shufflevector(p0, p1, 1, 3, 5, 7);
    const int m = n - base < 4 ? n - base : 4;
    for (int i = 0; i < m; ++i) out[base + i] += sums[i];
  }
}

// dst = v, quarter by quarter (an aggregate copy may go through a stack temporary).
static inline void assign(vf& dst, vf v) {
  for (int k = 0; k < kQuarters; ++k) dst.h[k] = v.h[k];
}

// a < b ? a : b and a > b ? a : b (NaN and ties give b, as the x86 layers' min/max).
static inline vf vmin(vf a, vf b) { return vsel(a < b, a, b); }
static inline vf vmax(vf a, vf b) { return vsel(a > b, a, b); }

// Lane by lane through a builtin, in loops GCC vectorizes to the target's instruction (NEON:
// fmla, fsqrt, frintp, frintm; x86: vfmadd with FMA, sqrtps, roundps). Where a target has no
// fused multiply-add, fmaf is still fused (a library call): never two roundings.
#define RASTER_LANEWISE(expr)                                  \
  vf r;                                                        \
  for (int k = 0; k < kQuarters; ++k)                          \
    for (int l = 0; l < 4; ++l) r.h[k][l] = (expr);            \
  return r

// a * b + c and c - a * b, each with one rounding.
static inline vf vfmadd(vf a, vf b, vf c) {
  RASTER_LANEWISE(__builtin_fmaf(a.h[k][l], b.h[k][l], c.h[k][l]));
}
static inline vf vfnmadd(vf a, vf b, vf c) {
  RASTER_LANEWISE(__builtin_fmaf(-a.h[k][l], b.h[k][l], c.h[k][l]));
}
static inline vf vsqrt(vf x) { RASTER_LANEWISE(__builtin_sqrtf(x.h[k][l])); }
static inline vf vceil(vf x) { RASTER_LANEWISE(__builtin_ceilf(x.h[k][l])); }
static inline vf vfloor(vf x) { RASTER_LANEWISE(__builtin_floorf(x.h[k][l])); }
#undef RASTER_LANEWISE
#undef RASTER_PARTWISE

// The reciprocal's estimate for vrcp_refine: the quotient itself (rounded; the refinement
// keeps it). NEON's estimate (vrecpe, relative error 2^-8) is too coarse for one third-order
// step to reach the rounded reciprocal, and a division is the same everywhere.
static inline vf vrcp_estimate(vf x) { return 1.f / x; }
