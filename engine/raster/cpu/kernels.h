// Per-tile forward and backward blending kernels, written once with GCC vector extensions.
//
// This header is included by one translation unit per instruction set (kernels_avx2.cpp,
// kernels_avx512.cpp, kernels_portable.cpp); each defines RASTER_NS (the namespace) and
// RASTER_AVX512 (and RASTER_PORTABLE) before including it, so the same source is compiled for
// each target and raster.cpp picks one at run time.
// A tile is 16x16 pixels and one tile row (16 floats) is one vector: one zmm register on AVX-512,
// an explicit pair of ymm halves on AVX2 (see the types below). No OpenMP in here: raster.cpp parallelizes over tiles.
// RASTER_PORTABLE replaces the x86 vector layer below (types, masks, min/max, fused operations,
// sqrt/ceil/floor, the reciprocal's estimate) by vec_portable.h's, in generic vectors only: the
// variant that builds for any CPU (NEON on aarch64). Everything else is shared by all variants.
#ifndef RASTER_PORTABLE
#define RASTER_PORTABLE 0
#endif
#if !RASTER_PORTABLE
#include <immintrin.h>
#endif

#include <cmath>
#include <cstdint>

#include "common.h"

namespace RASTER_NS {

#if !RASTER_PORTABLE
// Sum of the 8 lanes of a ymm register.
static inline float hsum8(__m256 s8) {
  __m128 s4 = _mm_add_ps(_mm256_castps256_ps128(s8), _mm256_extractf128_ps(s8, 1));
  s4 = _mm_add_ps(s4, _mm_movehl_ps(s4, s4));
  s4 = _mm_add_ss(s4, _mm_movehdup_ps(s4));
  return _mm_cvtss_f32(s4);
}
#endif

#if RASTER_AVX512
// One zmm register per tile row: GCC vector extensions map 1:1 onto AVX-512.
typedef float vf __attribute__((vector_size(64)));
typedef int32_t vi __attribute__((vector_size(64)));

static inline vf vsel(vi m, vf a, vf b) { return m ? a : b; }
static inline vi vseli(vi m, vi a, vi b) { return m ? a : b; }
static inline vi to_int(vf x) { return __builtin_convertvector(x, vi); }
static inline vf to_float(vi x) { return __builtin_convertvector(x, vf); }
static inline vi bits_of(vf x) { return (vi)x; }
static inline vf from_bits(vi x) { return (vf)x; }

// Bit i set when lane i of the mask (0 or -1 per lane) is set.
static inline uint32_t movemask(vi m) { return (uint32_t)_mm512_movepi32_mask((__m512i)m); }

static inline float hsum(vf v) {
  const __m256 lo = __builtin_shufflevector(v, v, 0, 1, 2, 3, 4, 5, 6, 7);
  const __m256 hi = __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15);
  return hsum8(_mm256_add_ps(lo, hi));
}

// Sums of up to 16 vectors at once, lane i of the result = sum of the lanes of v[i]: a
// transposing tree (each level halves the lanes per vector and doubles the vectors per
// register), about a third of the instructions of one hsum per vector.
static inline vf sum2(vf a, vf b) {  // [a 8 partials | b 8 partials]
  return __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23) +
         __builtin_shufflevector(a, b, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30,
                                 31);
}
static inline vf sum4(vf a, vf b) {  // two sum2 results -> 4 partials each of 4 vectors
  return __builtin_shufflevector(a, b, 0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 24, 25, 26, 27) +
         __builtin_shufflevector(a, b, 4, 5, 6, 7, 12, 13, 14, 15, 20, 21, 22, 23, 28, 29, 30, 31);
}
static inline vf sum8(vf a, vf b) {  // -> 2 partials each of 8 vectors
  return __builtin_shufflevector(a, b, 0, 1, 4, 5, 8, 9, 12, 13, 16, 17, 20, 21, 24, 25, 28, 29) +
         __builtin_shufflevector(a, b, 2, 3, 6, 7, 10, 11, 14, 15, 18, 19, 22, 23, 26, 27, 30, 31);
}
static inline vf sum16(vf a, vf b) {  // -> the 16 sums, in order
  return __builtin_shufflevector(a, b, 0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30) +
         __builtin_shufflevector(a, b, 1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
}

// out[s] += sum of the lanes of v[s] for s < n (n <= 16); v[n..] are read as zero.
static inline void add_lane_sums(const vf* v, int n, float* out) {
  vf x[16];
  for (int i = 0; i < 16; ++i) x[i] = i < n ? v[i] : vf{};
  vf p[8], q[4], r[2];
  for (int i = 0; i < 8; ++i) p[i] = 2 * i < n ? sum2(x[2 * i], x[2 * i + 1]) : vf{};
  for (int i = 0; i < 4; ++i) q[i] = 4 * i < n ? sum4(p[2 * i], p[2 * i + 1]) : vf{};
  for (int i = 0; i < 2; ++i) r[i] = 8 * i < n ? sum8(q[2 * i], q[2 * i + 1]) : vf{};
  const vf sums = sum16(r[0], r[1]);
  const __mmask16 m = (__mmask16)((1u << n) - 1u);
  _mm512_mask_storeu_ps(out, m, _mm512_add_ps(_mm512_maskz_loadu_ps(m, out), (__m512)sums));
}
#elif RASTER_PORTABLE
#include "vec_portable.h"
#else
// AVX2 has no 512-bit registers, and GCC lowers 64-byte generic vectors poorly there: comparisons,
// ?: selects and __builtin_convertvector on them are scalarized lane by lane, and values bounce
// through the stack. So a tile row is an explicit pair of native 8-lane (ymm) halves, with the
// operators the kernels use defined half-wise; every operation below compiles to one ymm
// instruction per half.
typedef float hf __attribute__((vector_size(32), __may_alias__));
typedef int32_t hi __attribute__((vector_size(32), __may_alias__));
constexpr int kParts = 2;  // vec_split.h: the row types, their operators and conversions
typedef hf pf;
typedef hi pi;
#include "vec_split.h"

// Selects by vblendvps, which reads each lane's sign bit: the masks here are all 0 / -1 lanes
// (comparisons and their and / andnot). GCC's ?: on a mask vector tests it against zero first,
// one more vpcmpeqd per half and select (seen in the forward's job loop).
static inline hf blendv(hi m, hf a, hf b) {
  return (hf)_mm256_blendv_ps((__m256)b, (__m256)a, (__m256)m);
}
static inline vf vsel(vi m, vf a, vf b) {
  return vf{{blendv(m.h[0], a.h[0], b.h[0]), blendv(m.h[1], a.h[1], b.h[1])}};
}
static inline vi vseli(vi m, vi a, vi b) {
  return vi{{(hi)blendv(m.h[0], (hf)a.h[0], (hf)b.h[0]),
             (hi)blendv(m.h[1], (hf)a.h[1], (hf)b.h[1])}};
}

// Bit i set when lane i of the mask (0 or -1 per lane) is set.
static inline uint32_t movemask(vi m) {
  const uint32_t a = (uint32_t)_mm256_movemask_ps((__m256)m.h[0]);
  const uint32_t b = (uint32_t)_mm256_movemask_ps((__m256)m.h[1]);
  return a | (b << 8);
}

static inline float hsum(vf v) { return hsum8((__m256)(v.h[0] + v.h[1])); }

// As the AVX-512 add_lane_sums: the two halves are added first, then a transposing tree over
// 8-lane registers (up to 8 vectors per register).
static inline hf hsum2(hf a, hf b) {  // [a 4 partials | b 4 partials]
  return __builtin_shufflevector(a, b, 0, 1, 2, 3, 8, 9, 10, 11) +
         __builtin_shufflevector(a, b, 4, 5, 6, 7, 12, 13, 14, 15);
}
static inline hf hsum4(hf a, hf b) {  // -> 2 partials each of 4 vectors
  return __builtin_shufflevector(a, b, 0, 1, 4, 5, 8, 9, 12, 13) +
         __builtin_shufflevector(a, b, 2, 3, 6, 7, 10, 11, 14, 15);
}
static inline hf hsum8v(hf a, hf b) {  // -> the 8 sums, in order
  return __builtin_shufflevector(a, b, 0, 2, 4, 6, 8, 10, 12, 14) +
         __builtin_shufflevector(a, b, 1, 3, 5, 7, 9, 11, 13, 15);
}

static inline void add_lane_sums(const vf* v, int n, float* out) {
  hf x[16];
  for (int i = 0; i < 16; ++i) x[i] = i < n ? v[i].h[0] + v[i].h[1] : hf{};
  for (int half = 0; half < 2; ++half) {
    const int base = 8 * half;
    if (base >= n) break;
    const hf* y = x + base;
    const hf p0 = hsum2(y[0], y[1]), p1 = hsum2(y[2], y[3]);
    const hf p2 = hsum2(y[4], y[5]), p3 = hsum2(y[6], y[7]);
    const hf sums = hsum8v(hsum4(p0, p1), hsum4(p2, p3));
    const int m = n - base < 8 ? n - base : 8;
    for (int i = 0; i < m; ++i) out[base + i] += sums[i];
  }
}
#undef RASTER_PARTWISE
#endif

// dst = v. On AVX2 a plain aggregate copy of a value that stays live afterwards is done by GCC in
// 16-byte pieces through a stack temporary; copying the halves keeps it to two ymm stores.
#if !RASTER_PORTABLE  // (portable: vec_portable.h, as vmin/vmax, the fused operations,
                      // vrcp_estimate and vsqrt/vceil/vfloor below)
static inline void assign(vf& dst, vf v) {
#if RASTER_AVX512
  dst = v;
#else
  dst.h[0] = v.h[0];
  dst.h[1] = v.h[1];
#endif
}
#endif

static inline vf splat(float x) { return vf{} + x; }
static inline vi splati(int32_t x) { return vi{} + x; }
// a < b ? a : b and a > b ? a : b. On AVX2 GCC emits compare + blendv for the ?: form, so the
// min/max intrinsics (the same semantics: NaN and ties give b) are used there.
#if RASTER_AVX512
static inline vf vmin(vf a, vf b) { return vsel(a < b, a, b); }
static inline vf vmax(vf a, vf b) { return vsel(a > b, a, b); }
#elif !RASTER_PORTABLE
static inline vf vmin(vf a, vf b) {
  return vf{{(hf)_mm256_min_ps((__m256)a.h[0], (__m256)b.h[0]),
             (hf)_mm256_min_ps((__m256)a.h[1], (__m256)b.h[1])}};
}
static inline vf vmax(vf a, vf b) {
  return vf{{(hf)_mm256_max_ps((__m256)a.h[0], (__m256)b.h[0]),
             (hf)_mm256_max_ps((__m256)a.h[1], (__m256)b.h[1])}};
}
#endif

// Lane masks of comparisons (vm). On AVX-512 a vm is a mask register (__mmask16, one bit per
// lane): comparisons write it directly, and/andnot are single k-register operations, and
// selects are masked moves. As a 0/-1 vector, as on AVX2, every mask is materialised in a
// vector register and converted back for each select, which cost several instructions per
// blend and the register pressure that pushed the blend's running state out to memory.
#if RASTER_AVX512
typedef __mmask16 vm;
static inline vm m_ge(vf a, float b) {
  return _mm512_cmp_ps_mask((__m512)a, _mm512_set1_ps(b), _CMP_GE_OQ);
}
static inline vm m_le(vf a, float b) {
  return _mm512_cmp_ps_mask((__m512)a, _mm512_set1_ps(b), _CMP_LE_OQ);
}
static inline vm m_and(vm a, vm b) { return (vm)(a & b); }
static inline vm m_andnot(vm a, vm b) { return (vm)(a & ~b); }  // a and not b
static inline uint32_t m_bits(vm m) { return m; }
static inline vf m_sel(vm m, vf a, vf b) {
  return (vf)_mm512_mask_blend_ps(m, (__m512)b, (__m512)a);
}
static inline vi m_seli(vm m, vi a, vi b) {
  return (vi)_mm512_mask_blend_epi32(m, (__m512i)b, (__m512i)a);
}
static inline vf m_mulz(vm m, vf a, vf b) {  // a * b where m is set, else 0
  return (vf)_mm512_maskz_mul_ps(m, (__m512)a, (__m512)b);
}
static inline vm m_of(vi m) { return _mm512_movepi32_mask((__m512i)m); }
static inline vm m_lti(vi a, vi b) { return _mm512_cmplt_epi32_mask((__m512i)a, (__m512i)b); }
static inline bool m_any(vm m) { return m != 0; }
#elif !RASTER_PORTABLE
// AVX2: masks as 0 / -1 vectors. and-not and the zeroing multiply by one instruction per half
// (GCC spelled a & ~b as vpxor with all ones, then vpand), and "any lane set" by one vtestps on
// the halves' union instead of two vmovmskps and their merge.
typedef vi vm;
static inline vm m_ge(vf a, float b) { return a >= b; }
static inline vm m_le(vf a, float b) { return a <= b; }
static inline vm m_and(vm a, vm b) { return a & b; }
static inline vm m_andnot(vm a, vm b) {  // a and not b
  return vm{{(hi)_mm256_andnot_ps((__m256)b.h[0], (__m256)a.h[0]),
             (hi)_mm256_andnot_ps((__m256)b.h[1], (__m256)a.h[1])}};
}
static inline uint32_t m_bits(vm m) { return movemask(m); }
static inline bool m_any(vm m) {
  const __m256 u = _mm256_or_ps((__m256)m.h[0], (__m256)m.h[1]);
  return !_mm256_testz_ps(u, u);
}
static inline vf m_sel(vm m, vf a, vf b) { return vsel(m, a, b); }
static inline vi m_seli(vm m, vi a, vi b) { return vseli(m, a, b); }
static inline vf m_mulz(vm m, vf a, vf b) {  // a * b where m is set, else 0
  const vf p = a * b;
  return vf{{(hf)_mm256_and_ps((__m256)m.h[0], (__m256)p.h[0]),
             (hf)_mm256_and_ps((__m256)m.h[1], (__m256)p.h[1])}};
}
static inline vm m_of(vi m) { return m; }
static inline vm m_lti(vi a, vi b) { return a < b; }
#else
typedef vi vm;
static inline vm m_ge(vf a, float b) { return a >= b; }
static inline vm m_le(vf a, float b) { return a <= b; }
static inline vm m_and(vm a, vm b) { return a & b; }
static inline vm m_andnot(vm a, vm b) { return a & ~b; }
static inline uint32_t m_bits(vm m) { return movemask(m); }
static inline bool m_any(vm m) { return movemask(m) != 0; }
static inline vf m_sel(vm m, vf a, vf b) { return vsel(m, a, b); }
static inline vi m_seli(vm m, vi a, vi b) { return vseli(m, a, b); }
static inline vf m_mulz(vm m, vf a, vf b) { return vsel(m, a * b, vf{}); }
static inline vm m_of(vi m) { return m; }
static inline vm m_lti(vi a, vi b) { return a < b; }
#endif

// exp(-p[i]) for K vectors p >= 0, to ~2 ulp: range reduction by ln 2 (n the nearest integer
// to -p / ln 2), the degree-7 Taylor polynomial of the remainder, then the scaling by 2^n. p is
// clamped to 87 (exp(-87) is about the smallest normal float). Taking p rather than x = -p
// spares the negation and lets the clamp be one vminps. On AVX-512 the rounding and the scaling
// are one instruction each (vrndscaleps, vscalefps); AVX2 goes through integers.
//
// The kernels are bound by this function's dependency chain more than by its operation count,
// so the polynomial is evaluated by Estrin's scheme (pairs, then the powers r^2 and r^4: a
// chain of 4 operations instead of Horner's 7), and K > 1 exponentials are computed step by
// step side by side, which keeps independent work next to each other in the instruction stream.
//
// always_inline: on AVX2 GCC's inliner judged the two-vector instance (vexp_neg_n<2>, twice as
// many instructions as on AVX-512, each row operation being two ymm ones) too large and called
// it out of line from the forward's job loop. The SysV ABI has every ymm register caller-saved,
// so each call spilled the row's whole blend state (transmittance, live lanes, accumulators) to
// the stack and passed the powers and results through memory, behind a vzeroupper.
template <int K>
__attribute__((always_inline)) static inline void vexp_neg_n(const vf* pin, vf* out) {
  vf p[K], nf[K], r[K];
#if !RASTER_AVX512
  vi n[K];
#endif
  for (int i = 0; i < K; ++i) p[i] = vmin(pin[i], splat(87.0f));
  for (int i = 0; i < K; ++i) {
    const vf t = p[i] * -1.44269504088896341f;
#if RASTER_AVX512
    nf[i] = (vf)_mm512_roundscale_ps((__m512)t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
#else
    n[i] = to_int(t - 0.5f);  // round to nearest for t <= 0
    nf[i] = to_float(n[i]);
#endif
  }
  for (int i = 0; i < K; ++i) r[i] = -p[i] - nf[i] * 0.693145751953125f;
  for (int i = 0; i < K; ++i) r[i] = r[i] - nf[i] * 1.428606765330187045e-06f;
  vf r2[K], r4[K], p01[K], p23[K], p45[K], p67[K], q[K];
  for (int i = 0; i < K; ++i) r2[i] = r[i] * r[i];
  for (int i = 0; i < K; ++i) p01[i] = 1.0f + r[i];
  for (int i = 0; i < K; ++i) p23[i] = 0.5f + r[i] * (1.0f / 6.0f);
  for (int i = 0; i < K; ++i) p45[i] = (1.0f / 24.0f) + r[i] * (1.0f / 120.0f);
  for (int i = 0; i < K; ++i) p67[i] = (1.0f / 720.0f) + r[i] * (1.0f / 5040.0f);
  for (int i = 0; i < K; ++i) r4[i] = r2[i] * r2[i];
  for (int i = 0; i < K; ++i) p01[i] = p01[i] + r2[i] * p23[i];
  for (int i = 0; i < K; ++i) p45[i] = p45[i] + r2[i] * p67[i];
  for (int i = 0; i < K; ++i) q[i] = p01[i] + r4[i] * p45[i];
  for (int i = 0; i < K; ++i) {
#if RASTER_AVX512
    out[i] = (vf)_mm512_scalef_ps((__m512)q[i], (__m512)nf[i]);
#else
    out[i] = from_bits(bits_of(q[i]) + (n[i] << 23));
#endif
  }
}

__attribute__((always_inline)) static inline vf vexp_neg(vf p) {
  vf e;
  vexp_neg_n<1>(&p, &e);
  return e;
}

// a * b + c and c - a * b, each with one rounding (fused), spelled out so that the rounding does
// not depend on the compiler's contraction flags.
#if RASTER_AVX512
static inline vf vfmadd(vf a, vf b, vf c) {
  return (vf)_mm512_fmadd_ps((__m512)a, (__m512)b, (__m512)c);
}
static inline vf vfnmadd(vf a, vf b, vf c) {
  return (vf)_mm512_fnmadd_ps((__m512)a, (__m512)b, (__m512)c);
}
#elif !RASTER_PORTABLE
static inline vf vfmadd(vf a, vf b, vf c) {
  return vf{{(hf)_mm256_fmadd_ps((__m256)a.h[0], (__m256)b.h[0], (__m256)c.h[0]),
             (hf)_mm256_fmadd_ps((__m256)a.h[1], (__m256)b.h[1], (__m256)c.h[1])}};
}
static inline vf vfnmadd(vf a, vf b, vf c) {
  return vf{{(hf)_mm256_fnmadd_ps((__m256)a.h[0], (__m256)b.h[0], (__m256)c.h[0]),
             (hf)_mm256_fnmadd_ps((__m256)a.h[1], (__m256)b.h[1], (__m256)c.h[1])}};
}
#endif

// The hardware's reciprocal estimate of x: AVX-512's vrcp14ps (relative error < 2^-14), AVX2's
// vrcpps (< 1.5 * 2^-12). The estimate's actual values are the vendor's: Intel and AMD CPUs
// return different estimates for the same x, both within that bound.
#if !RASTER_PORTABLE
static inline vf vrcp_estimate(vf x) {
#if RASTER_AVX512
  return (vf)_mm512_rcp14_ps((__m512)x);
#else
  return vf{{(hf)_mm256_rcp_ps((__m256)x.h[0]), (hf)_mm256_rcp_ps((__m256)x.h[1])}};
#endif
}
#endif

// 1 / x from an estimate r with relative error d (r = (1 - d) / x, |d| <= 1.5 * 2^-12), by the
// third-order step r (1 + e + e^2) with e = 1 - x r = d computed by one fused operation: the
// result's relative error is d^3 (< 5e-11) plus its last rounding, so it is the rounded
// reciprocal on any CPU. The backward divides by 1 - alpha once per blended Gaussian and pixel
// to undo the transmittance, and an error in that quotient is not random: Newton's second-order
// step r (2 - x r) leaves -d^2 (every quotient too small, by up to 2.2 roundoffs with AVX2's
// estimate), which over a list of hundreds of faint Gaussians compounded into the recovered
// transmittances and failed the float64 comparison on AMD CPUs, whose estimates are less
// accurate than Intel's (issue 59). One more fused operation than Newton's step; a vector
// division cost more than the rest of the transmittance bookkeeping.
static inline vf vrcp_refine(vf x, vf r) {
  const vf e = vfnmadd(x, r, splat(1.f));
  return vfmadd(r, vfmadd(e, e, e), r);
}

// 1 / x for x in [0.001, 1] (here 1 - alpha with alpha <= 0.999), see vrcp_refine.
static inline vf vrcp(vf x) { return vrcp_refine(x, vrcp_estimate(x)); }

#if RASTER_AVX512
static inline vf vsqrt(vf x) { return (vf)_mm512_sqrt_ps((__m512)x); }
static inline vf vceil(vf x) {
  return (vf)_mm512_roundscale_ps((__m512)x, _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC);
}
static inline vf vfloor(vf x) {
  return (vf)_mm512_roundscale_ps((__m512)x, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
}
#elif !RASTER_PORTABLE
static inline vf vsqrt(vf x) {
  return vf{{(hf)_mm256_sqrt_ps((__m256)x.h[0]), (hf)_mm256_sqrt_ps((__m256)x.h[1])}};
}
static inline vf vceil(vf x) {
  return vf{{(hf)_mm256_ceil_ps((__m256)x.h[0]), (hf)_mm256_ceil_ps((__m256)x.h[1])}};
}
static inline vf vfloor(vf x) {
  return vf{{(hf)_mm256_floor_ps((__m256)x.h[0]), (hf)_mm256_floor_ps((__m256)x.h[1])}};
}
#endif

// How many list entries ahead the blend loops prefetch a Gaussian's record and features.
constexpr int32_t kPrefetch = 8;

// Bit r set for each tile row r whose pixel centres (v + 0.5) the Gaussian's cull ellipse
// crosses inside [x0, x0 + 16): all 16 rows tested at once, one vector lane per row, so the
// per-row loops below visit only rows that hit, without a data-dependent branch per row. dy
// receives each row's offset from the centre, g.my - (y0 + r + 0.5). The cull keeps a margin
// (GaussRec::two_a_t), so rounding here never drops a pixel that passes the alpha test. Rows
// past the image's last are the caller's to mask (rows that cannot blend). Inlined by force, as
// vexp_neg_n: the portable build called it out of line, its vectors passed through memory.
__attribute__((always_inline)) static inline uint32_t row_hit_mask(const GaussRec& g, int y0,
                                                                   int x0, vf row_index,
                                                                   vf& dy) {
  dy = g.my - (row_index + ((float)y0 + 0.5f));
  const vf disc = g.two_a_t - g.det * dy * dy;
  const vf half = vsqrt(vmax(disc, vf{})) * g.inv_a;
  const vf cx = g.mx + g.b * dy * g.inv_a;  // centre of each row's x interval
  const vf ulo = vceil(cx - half - 0.5f);
  const vf uhi = vfloor(cx + half - 0.5f);
  return movemask((disc >= 0.f) & (uhi >= (float)x0) & (ulo <= (float)(x0 + 15)));
}

// Gaussians per batch of the blend loops (see forward_tile_impl).
constexpr int kBatch = 32;

// One Gaussian of a batch: what every row it reaches shares.
struct BatchG {
  vf dx;         // centre x minus each lane's pixel centre
  vf dx2;        // a dx^2 / 2
  vf cdy2;       // c dy^2 / 2 for each tile row (lane r: row r)
  vf bdy;        // b dy for each tile row
  float o, z;    // opacity, depth
  const float* f;  // features
  int32_t pos;   // 1 + its position in the tile list
};

// Forward blending of one tile. acc is scratch of (C + 1) * 256 floats (64-byte aligned).
// CC: the channel count when known at compile time (the channel loops unroll), -1 for any.
template <int CC>
static void forward_tile_impl(const TileFwd& a, int tile_x, int tile_y, float* acc) {
  const int x0 = tile_x * TILE, y0 = tile_y * TILE;
  const int rows = a.height - y0 < TILE ? a.height - y0 : TILE;
  const int cols = a.width - x0 < TILE ? a.width - x0 : TILE;
  const int C = CC >= 0 ? CC : a.channels;
  vf* accv = reinterpret_cast<vf*>(acc);  // [(C + 1)][16 rows]
  for (int i = 0; i < (C + 1) * TILE; ++i) accv[i] = vf{};
  vf T[TILE];
  vi last[TILE];
  vm active[TILE];  // lanes still blending
  vf lanex, row_index;
  vi lane_in;
  for (int l = 0; l < TILE; ++l) {
    lanex[l] = (float)(x0 + l) + 0.5f;
    row_index[l] = (float)l;
    lane_in[l] = l < cols ? -1 : 0;
  }
  uint32_t live = rows >= 32 ? ~0u : (1u << rows) - 1;  // rows with a lane still blending
  for (int r = 0; r < TILE; ++r) {
    T[r] = splat(1.f);
    last[r] = vi{};
    active[r] = m_of(r < rows ? lane_in : vi{});
  }
  int64_t evaluated = 0, blended = 0;
  const int32_t begin = a.offsets[tile_y * a.tiles_x + tile_x];
  const int32_t end = a.offsets[tile_y * a.tiles_x + tile_x + 1];
  // The list is walked in batches of kBatch Gaussians: first each Gaussian's rows are listed,
  // row by row (in depth order within a row), then each row blends its list with its state
  // (transmittance, accumulators, last position, live lanes) held in registers. Blending
  // Gaussian by Gaussian instead kept that state in memory, indexed by row, and every blend
  // waited on the previous one's stores to the same row.
  BatchG bg[kBatch];
  uint8_t jobs[TILE][kBatch];  // per row: the batch's Gaussians that reach it, in depth order
  int count[TILE];
  int32_t j = begin;
  while (j < end && live) {
    int nb = 0;
    for (int r = 0; r < TILE; ++r) count[r] = 0;
    for (; j < end && nb < kBatch; ++j) {
      // The list visits records in depth order but far apart in memory: fetch ahead.
      if (j + kPrefetch < end) {
        const int32_t ahead = a.list[j + kPrefetch];
        __builtin_prefetch(a.recs + ahead);
        __builtin_prefetch(a.feats + (int64_t)ahead * C);
      }
      const int32_t rank = a.list[j];
      const GaussRec& g = a.recs[rank];
      vf dy;
      uint32_t hits = row_hit_mask(g, y0, x0, row_index, dy) & live;
      if (!hits) continue;
      BatchG& b = bg[nb];
      b.dx = g.mx - lanex;
      b.dx2 = 0.5f * g.a * b.dx * b.dx;
      b.cdy2 = 0.5f * g.c * dy * dy;
      b.bdy = g.b * dy;
      b.o = g.o;
      b.z = g.z;
      b.f = a.feats + (int64_t)rank * C;
      b.pos = j - begin + 1;
      for (; hits; hits &= hits - 1) {
        const int r = __builtin_ctz(hits);
        jobs[r][count[r]++] = (uint8_t)nb;
      }
      ++nb;
    }
    for (int r = 0; r < rows; ++r) {
      const int n = count[r];
      if (!n || !(live >> r & 1)) continue;
      evaluated += (int64_t)TILE * n;
      vf t_r = T[r];
      vm act = active[r];
      vi lst = last[r];
      vf acc_r[(CC >= 0 ? CC : 0) + 1];
      if constexpr (CC >= 0)
        for (int k = 0; k <= C; ++k) acc_r[k] = accv[k * TILE + r];
      // Blends one job; true when it leaves every lane of the row stopped. Inlined by force: the
      // portable build's vectors (four quarters) made GCC call it out of line, with the row's
      // state passed through memory.
      auto blend_one = [&](const BatchG& b, vf power,
                           vf alpha) __attribute__((always_inline)) -> bool {
        const vm valid = m_and(m_and(act, m_ge(power, 0.f)), m_ge(alpha, kAlphaMin));
        const vf next_t = t_r * (1.f - alpha);
        const vm stop = m_and(valid, m_le(next_t, kMinTransmittance));
        const vm blend = m_andnot(valid, stop);
        // No branch on "any lane blends": it depends on the exp, and a misprediction exposes
        // that latency chain. Lanes that do not blend add exact zeros.
        blended += __builtin_popcount(m_bits(blend));
        const vf w = m_mulz(blend, alpha, t_r);
        if constexpr (CC >= 0) {
          for (int k = 0; k < C; ++k) acc_r[k] += w * b.f[k];
          acc_r[C] += w * b.z;
        } else {
          for (int k = 0; k < C; ++k) accv[k * TILE + r] += w * b.f[k];
          accv[C * TILE + r] += w * b.z;
        }
        t_r = m_sel(blend, next_t, t_r);
        lst = m_seli(blend, splati(b.pos), lst);
        if (m_any(stop)) {
          act = m_andnot(act, stop);
          if (!m_any(act)) {
            live &= ~(1u << r);
            return true;
          }
        }
        return false;
      };
      // Two jobs at a time: their exponentials (the long chains) side by side, then the two
      // blends in depth order.
      int q = 0;
      for (; q + 1 < n; q += 2) {
        const BatchG& b0 = bg[jobs[r][q]];
        const BatchG& b1 = bg[jobs[r][q + 1]];
        const vf power[2] = {b0.dx2 + b0.cdy2[r] + b0.bdy[r] * b0.dx,
                             b1.dx2 + b1.cdy2[r] + b1.bdy[r] * b1.dx};
        vf e[2];
        vexp_neg_n<2>(power, e);
        const vf alpha0 = vmin(splat(0.999f), b0.o * e[0]);
        const vf alpha1 = vmin(splat(0.999f), b1.o * e[1]);
        if (blend_one(b0, power[0], alpha0) || blend_one(b1, power[1], alpha1)) break;
      }
      if (q + 1 == n) {
        const BatchG& b = bg[jobs[r][q]];
        const vf power = b.dx2 + b.cdy2[r] + b.bdy[r] * b.dx;
        blend_one(b, power, vmin(splat(0.999f), b.o * vexp_neg(power)));
      }
      assign(T[r], t_r);
      active[r] = act;
      last[r] = lst;
      if constexpr (CC >= 0)
        for (int k = 0; k <= C; ++k) assign(accv[k * TILE + r], acc_r[k]);
    }
  }
  for (int r = 0; r < rows; ++r) {
    const int64_t base = (int64_t)(y0 + r) * a.width + x0;
    for (int l = 0; l < cols; ++l) {
      const float t = T[r][l];
      for (int k = 0; k < C; ++k)
        a.image[(int64_t)k * a.height * a.width + base + l] = accv[k * TILE + r][l] + t * a.bg[k];
      a.depth[base + l] = accv[C * TILE + r][l];
      a.alpha[base + l] = 1.f - t;
      if (a.t_final) a.t_final[base + l] = t;
      if (a.last) a.last[base + l] = last[r][l];
    }
  }
  a.evaluated[tile_y * a.tiles_x + tile_x] = evaluated;
  a.blended[tile_y * a.tiles_x + tile_x] = blended;
}

void forward_tile(const TileFwd& a, int tile_x, int tile_y, float* acc) {
  switch (a.channels) {  // the channel counts the trainer uses
    case 0: return forward_tile_impl<0>(a, tile_x, tile_y, acc);
    case 3: return forward_tile_impl<3>(a, tile_x, tile_y, acc);
    default: return forward_tile_impl<-1>(a, tile_x, tile_y, acc);
  }
}

// Backward of one tile: walks the tile's list back to front, undoing the transmittance, and adds
// per-Gaussian gradients (layout GradLayout) into grad (this thread's buffer, indexed by rank).
// scratch holds (C + 2) * 256 + S * 16 floats (64-byte aligned). Geo = false skips the 2D mean
// and conic gradients (their slots stay zero): the soft-depth pass trains opacities only.
// Op = true also reads v_depth_opacity, whose dL/dalpha_i reaches the opacity slot only.
// CC: the channel count when known at compile time, -1 for any.
//
// The per-pixel algebra is arranged to cost few vector operations per Gaussian-row, since the
// kernel is compute-bound:
// - dL/dalpha_i = sum_k (f_ik T_i - A_ik / (1 - alpha_i)) g_k + K T_final / (1 - alpha_i), with
//   A_ik = sum over later Gaussians j of w_j f_jk and g_k = dL/dout_k (depth as channel C). The
//   channels enter only through fg_i = sum_k f_ik g_k and B_i = sum_k A_ik g_k, and B grows by
//   w_i fg_i from one Gaussian to the next: one running B per pixel instead of C + 1 running
//   A_k, and dL/dalpha_i = T_i fg_i + (K T_final - B_i) / (1 - alpha_i).
// - The 2D mean and conic gradients are sums over the tile's rows of polynomials in dy (a
//   scalar per row) times v_sigma: each lane keeps sum v_sigma, sum dy v_sigma and
//   sum dy^2 v_sigma, and the five gradients are formed from those once per Gaussian.
template <bool Geo, bool Op, int CC>
static void backward_tile_impl(const TileBwd& a, int tile_x, int tile_y, float* scratch,
                               float* grad) {
  const int x0 = tile_x * TILE, y0 = tile_y * TILE;
  const int rows = a.height - y0 < TILE ? a.height - y0 : TILE;
  const int cols = a.width - x0 < TILE ? a.width - x0 : TILE;
  const int C = CC >= 0 ? CC : a.channels;
  const int S = C + kGradFixed;
  vf* vimg = reinterpret_cast<vf*>(scratch);  // [(C + 1)][16]: dL/dimage, dL/ddepth last
  vf* gacc = vimg + (C + 1) * TILE;            // [S]: per-Gaussian accumulators
  vf* vop = gacc + S;                          // [16]: dL/ddepth of the opacity-only loss
  vf T[TILE], kbg[TILE];
  vf behind[TILE];    // B: sum over later Gaussians of w * (sum_k f_k dL/dout_k), per pixel
  vf behind_z[TILE];  // sum over later Gaussians of w z (the depth behind), for Op only
  vi last[TILE];
  vi row_last = vi{};  // per row (as a lane): 1 + the last list position any pixel blended
  vf lanex, row_index;
  for (int l = 0; l < TILE; ++l) {
    lanex[l] = (float)(x0 + l) + 0.5f;
    row_index[l] = (float)l;
  }
  int max_last = 0;
  for (int r = 0; r < TILE; ++r) {
    T[r] = vf{};
    kbg[r] = vf{};
    behind[r] = vf{};
    behind_z[r] = vf{};
    last[r] = vi{};
    row_last[r] = 0;
    for (int k = 0; k <= C; ++k) vimg[k * TILE + r] = vf{};
    if constexpr (Op) vop[r] = vf{};
    if (r >= rows) continue;
    const int64_t base = (int64_t)(y0 + r) * a.width + x0;
    for (int l = 0; l < cols; ++l) {
      if constexpr (Op) vop[r][l] = a.v_depth_opacity[base + l];
      const float t = a.t_final[base + l];
      float k_bg = a.v_alpha[base + l];
      for (int k = 0; k < C; ++k) {
        const float g = a.v_image[(int64_t)k * a.height * a.width + base + l];
        vimg[k * TILE + r][l] = g;
        k_bg -= a.bg[k] * g;
      }
      vimg[C * TILE + r][l] = a.v_depth[base + l];
      T[r][l] = t;
      kbg[r][l] = t * k_bg;  // d/dalpha_i of T_final (alpha output and background) is T_final/(1-a_i)
      const int32_t n = a.last[base + l];
      last[r][l] = n;
      if (n > row_last[r]) row_last[r] = n;
    }
    if (row_last[r] > max_last) max_last = row_last[r];
  }
  const int32_t begin = a.offsets[tile_y * a.tiles_x + tile_x];
  for (int32_t jj = max_last - 1; jj >= 0; --jj) {
    if (jj >= kPrefetch) {  // as in the forward, and the gradient row written at the end
      const int32_t ahead = a.list[begin + jj - kPrefetch];
      __builtin_prefetch(a.recs + ahead);
      __builtin_prefetch(a.feats + (int64_t)ahead * C);
      // A row of S floats may straddle two cache lines: fetch both ends.
      __builtin_prefetch(grad + (int64_t)ahead * S, 1);
      __builtin_prefetch(grad + (int64_t)ahead * S + (S - 1), 1);
    }
    const int32_t rank = a.list[begin + jj];
    const GaussRec& g = a.recs[rank];
    const float* f = a.feats + (int64_t)rank * C;
    // Rows where some pixel blended this Gaussian or a later one, and the ellipse reaches.
    vf dyv;
    uint32_t hits = row_hit_mask(g, y0, x0, row_index, dyv) & movemask(splati(jj) < row_last);
    if (!hits) continue;
    const vf dx = g.mx - lanex;
    const vf dx2 = 0.5f * g.a * dx * dx;
    // Each row's terms as vectors over the tile's rows (lane r: row r), read back one lane per
    // row as a broadcast operand.
    alignas(64) float row_terms[4][TILE];
    *reinterpret_cast<vf*>(row_terms[0]) = 0.5f * g.c * dyv * dyv;  // c dy^2 / 2
    *reinterpret_cast<vf*>(row_terms[1]) = g.b * dyv;               // b dy
    *reinterpret_cast<vf*>(row_terms[2]) = dyv;
    *reinterpret_cast<vf*>(row_terms[3]) = dyv * dyv;
    // Every row the ellipse reaches is evaluated without a branch on "any lane valid": that
    // test is data dependent, and each misprediction exposed the exp's latency chain. Invalid
    // lanes contribute exact zeros (w = 0, masked alpha gradients) and keep their state.
    // The opacity, depth and channel accumulators: local (registers) when the channel count is
    // known at compile time, else the scratch slots. In scratch, every row's update waited on
    // the previous row's store to the same slot.
    constexpr int kLocal = CC >= 0 ? CC + kGradFixed - kGradO : 1;
    vf local[kLocal];
    auto acc = [&](int s) -> vf& { return CC >= 0 ? local[s - kGradO] : gacc[s]; };
    for (int s = kGradO; s < S; ++s) acc(s) = vf{};
    vf q0 = vf{}, q1 = vf{}, q2 = vf{};  // per lane: sum of oe dL/dalpha, times 1, dy, dy^2
    const vi jj_v = splati(jj);
    for (; hits; hits &= hits - 1) {
      const int r = __builtin_ctz(hits);
      const vf power = dx2 + row_terms[0][r] + row_terms[1][r] * dx;
      const vf e = vexp_neg(power);
      const vf oe = g.o * e;
      const vf alpha = vmin(splat(0.999f), oe);
      const vm valid =
          m_and(m_and(m_lti(jj_v, last[r]), m_ge(power, 0.f)), m_ge(alpha, kAlphaMin));
      const vf ra = vrcp(1.f - alpha);
      const vf t_before = m_sel(valid, T[r] * ra, T[r]);
      assign(T[r], t_before);
      const vf w = m_mulz(valid, alpha, t_before);
      // fg = sum_k f_k dL/dout_k over the colour channels and depth.
      const vf gd = vimg[C * TILE + r];
      vf fg = g.z * gd;
      for (int k = 0; k < C; ++k) {
        const vf gk = vimg[k * TILE + r];
        fg += f[k] * gk;
        acc(kGradFixed + k) += w * gk;
      }
      acc(kGradZ) += w * gd;
      const vf v_alpha = t_before * fg + (kbg[r] - behind[r]) * ra;
      // w is zero where the pixel does not blend this Gaussian: the running sums keep their value.
      behind[r] += w * fg;
      // The 0.999 clamp has no gradient (gsplat: only when o * exp(-power) <= 0.999).
      const vm live = m_and(valid, m_le(oe, 0.999f));
      const vf va = m_sel(live, v_alpha, vf{});
      if constexpr (Op) {
        // d(depth)/d(alpha_i), for the depth gradient that reaches the opacity alone.
        const vf dz = g.z * t_before - behind_z[r] * ra;
        behind_z[r] += w * g.z;
        acc(kGradO) += e * m_sel(live, v_alpha + dz * vop[r], vf{});
      } else {
        acc(kGradO) += e * va;
      }
      if constexpr (Geo) {
        const vf s = oe * va;  // -dL/dpower
        q0 += s;
        q1 += row_terms[2][r] * s;
        q2 += row_terms[3][r] * s;
      }
    }
    if constexpr (CC >= 0)
      for (int s = kGradO; s < S; ++s) assign(gacc[s], local[s - kGradO]);
    if constexpr (Geo) {
      // dL/dpower = -s and power = a dx^2 / 2 + b dx dy + c dy^2 / 2, summed over the rows.
      gacc[kGradA] = -(0.5f * dx * dx) * q0;
      gacc[kGradB] = -dx * q1;
      gacc[kGradC] = -0.5f * q2;
      gacc[kGradX] = -(g.a * dx * q0 + g.b * q1);
      gacc[kGradY] = -(g.b * dx * q0 + g.c * q1);
    } else {
      for (int s = 0; s < kGradO; ++s) gacc[s] = vf{};
    }
    {
      float* out = grad + (int64_t)rank * S;
      if (S <= 16) {
        // Without Geo the geometry slots hold zeros: adding them is a no-op, and one tree over
        // all S slots is cheaper than skipping them.
        add_lane_sums(gacc, S, out);
      } else {
        for (int s = Geo ? 0 : kGradO; s < S; ++s) out[s] += hsum(gacc[s]);
      }
    }
  }
}

template <bool Geo, bool Op>
static void backward_tile_channels(const TileBwd& a, int tile_x, int tile_y, float* scratch,
                                   float* grad) {
  switch (a.channels) {  // the channel counts the trainer uses
    case 0: return backward_tile_impl<Geo, Op, 0>(a, tile_x, tile_y, scratch, grad);
    case 3: return backward_tile_impl<Geo, Op, 3>(a, tile_x, tile_y, scratch, grad);
    default: return backward_tile_impl<Geo, Op, -1>(a, tile_x, tile_y, scratch, grad);
  }
}

void backward_tile(const TileBwd& a, int tile_x, int tile_y, float* scratch, float* grad) {
  const bool op = a.v_depth_opacity != nullptr;
  if (a.geometry)
    op ? backward_tile_channels<true, true>(a, tile_x, tile_y, scratch, grad)
       : backward_tile_channels<true, false>(a, tile_x, tile_y, scratch, grad);
  else
    op ? backward_tile_channels<false, true>(a, tile_x, tile_y, scratch, grad)
       : backward_tile_channels<false, false>(a, tile_x, tile_y, scratch, grad);
}

// out[i] = vrcp_refine(x[i], estimate[i]), 16 at a time (a partial last vector is padded with
// ones): the reciprocal the backward uses, from a caller's estimate.
void reciprocal(const float* x, const float* estimate, float* out, int64_t n) {
  for (int64_t i = 0; i < n; i += TILE) {
    vf xv = splat(1.f), rv = splat(1.f);
    const int m = n - i < TILE ? (int)(n - i) : TILE;
    for (int l = 0; l < m; ++l) {
      xv[l] = x[i + l];
      rv[l] = estimate[i + l];
    }
    const vf y = vrcp_refine(xv, rv);
    for (int l = 0; l < m; ++l) out[i + l] = y[l];
  }
}

}  // namespace RASTER_NS
