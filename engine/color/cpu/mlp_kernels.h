// The colour field's two bias-free MLPs, fused: forward and backward over one block of points at
// a time, written once with GCC vector extensions and included by one translation unit per
// instruction set (mlp_avx2.cpp, mlp_avx512.cpp define MLP_NS and MLP_AVX512; on CPUs other
// than x86, mlp_portable.cpp defines MLP_PORTABLE: generic vectors, no intrinsics).
//
// Why not torch's GEMMs: every product here has an inner size of 3 to 80, where MKL reaches about
// a third of this CPU's peak and packs its operands first, and each ReLU and its backward is one
// more pass over an (N, 64) array in memory. Here a block of kBlock points goes through every
// layer while its activations stay in L1/L2, each product keeps a register tile of accumulators
// (rows x 64 columns) and streams the weights from L1, and the ReLUs and their masks are applied
// as the tile is stored.
//
// Every product sums its inner index in ascending order, one fused multiply-add at a time, so a
// point's outputs do not depend on the block or the thread that computed it. The weight
// gradients sum a chunk's points block by block (mlp.cpp adds the chunks' sums in chunk order),
// so they do not depend on the thread count either.
#if !MLP_PORTABLE
#include <immintrin.h>
#endif

#include <cmath>
#include <cstdint>

#include "common.h"

namespace MLP_NS {

#if MLP_PORTABLE
// GCC generic 16-byte vectors: one q register on aarch64's NEON (32 of them).
constexpr int W = 4;
typedef float vf __attribute__((vector_size(16)));
static inline vf load(const float* p) {
  vf v;
  __builtin_memcpy(&v, p, sizeof v);
  return v;
}
static inline void store(float* p, vf v) { __builtin_memcpy(p, &v, sizeof v); }
static inline vf bcast(float x) { return vf{x, x, x, x}; }
// fmaf lane by lane (GCC vectorizes it to fmla): fused, as the x86 intrinsics are.
static inline vf fmadd(vf a, vf b, vf c) {
  vf r;
  for (int i = 0; i < W; ++i) r[i] = __builtin_fmaf(a[i], b[i], c[i]);
  return r;
}
// As the x86 max(0, x): 0 > x ? 0 : x, so a NaN x passes (as torch.relu).
static inline vf relu(vf x) { return vf{} > x ? vf{} : x; }
constexpr int kAccumulators = 16;
#else
// x86: the same operations at either width; MLP_X86(op) names the width's intrinsic _mm*_op.
#if MLP_AVX512
constexpr int W = 16;  // floats per vector
typedef __m512 vx;
#define MLP_X86(op) _mm512_##op
constexpr int kAccumulators = 16;  // vector registers one product tile accumulates in (of 32)
#else
constexpr int W = 8;
typedef __m256 vx;
#define MLP_X86(op) _mm256_##op
constexpr int kAccumulators = 8;  // of AVX2's 16 registers
#endif
typedef float vf __attribute__((vector_size(sizeof(vx))));
static inline vf load(const float* p) { return (vf)MLP_X86(loadu_ps)(p); }
static inline void store(float* p, vf v) { MLP_X86(storeu_ps)(p, (vx)v); }
static inline vf bcast(float x) { return (vf)MLP_X86(set1_ps)(x); }
static inline vf fmadd(vf a, vf b, vf c) {
  return (vf)MLP_X86(fmadd_ps)((vx)a, (vx)b, (vx)c);
}
// max(0, x) with the operands in this order returns x when x is NaN, as torch.relu does.
static inline vf relu(vf x) { return (vf)MLP_X86(max_ps)(MLP_X86(setzero_ps)(), (vx)x); }
#undef MLP_X86
#endif
// x where m > 0, else 0 (ReLU backward: a NaN activation passes no gradient, as in torch). One
// compare (ordered: false for NaN) and a masked move or an and, on each target.
static inline vf where_positive(vf m, vf x) { return m > vf{} ? x : vf{}; }

// What a product tile does with its sums before storing them.
enum Epilogue { kPlain, kRelu, kWherePositive };

// One register tile: for rows r < R and the CV * W columns at w, out[r] = (sum over k < K of
// in(r, k) * w[k * ldw], in ascending k) [+ init[r]], then the epilogue (kWherePositive keeps the
// entries whose mask[r] entry is > 0). in(r, k) = in[r * rs + k * ks], so the same tile
// multiplies by a row-major matrix (ks = 1) or by the transpose of one (rs = 1: weight gradients).
// init is added after the sum, not summed into: a weight gradient's running total over a
// chunk's points then takes one rounding per block of points, not one per point (the error of a
// sum over n points grows with the number of additions into one running value: n / kMlpBlock
// here, about torch's blocked GEMM, instead of n).
template <int R, int CV, Epilogue E>
static inline void tile(const float* in, int64_t rs, int64_t ks, int K, const float* w,
                        int64_t ldw, const float* init, int64_t ldi, float* out, int64_t ldo,
                        const float* mask, int64_t ldm) {
  vf acc[R][CV];
  for (int r = 0; r < R; ++r)
    for (int c = 0; c < CV; ++c) acc[r][c] = vf{};
  for (int k = 0; k < K; ++k) {
    vf wk[CV];
    for (int c = 0; c < CV; ++c) wk[c] = load(w + k * ldw + c * W);
    for (int r = 0; r < R; ++r) {
      const vf a = bcast(in[r * rs + k * ks]);
      for (int c = 0; c < CV; ++c) acc[r][c] = fmadd(a, wk[c], acc[r][c]);
    }
  }
  for (int r = 0; r < R; ++r)
    for (int c = 0; c < CV; ++c) {
      vf v = acc[r][c];
      if (init) v += load(init + r * ldi + c * W);
      if constexpr (E == kRelu) v = relu(v);
      if constexpr (E == kWherePositive) v = where_positive(load(mask + r * ldm + c * W), v);
      store(out + r * ldo + c * W, v);
    }
}

// out (rows x M) = [init +] in (rows x K) @ w (K x M), with the epilogue: register tiles of
// R rows x CV vectors over the columns, then the leftover rows one at a time.
template <int M, Epilogue E>
static void product(int rows, const float* in, int64_t rs, int64_t ks, int K, const float* w,
                    int64_t ldw, const float* init, int64_t ldi, float* out, int64_t ldo,
                    const float* mask = nullptr, int64_t ldm = 0) {
  static_assert(M % W == 0, "the column count must be a whole number of vectors");
  constexpr int CV = M / W < 4 ? M / W : 4;
  constexpr int R = kAccumulators / CV;
  static_assert(M % (CV * W) == 0, "columns split into whole tiles");
  for (int c0 = 0; c0 < M; c0 += CV * W) {
    const float* ic = init ? init + c0 : nullptr;
    const float* mc = mask ? mask + c0 : nullptr;
    int r = 0;
    for (; r + R <= rows; r += R)
      tile<R, CV, E>(in + r * rs, rs, ks, K, w + c0, ldw, ic ? ic + r * ldi : nullptr, ldi,
                     out + r * ldo + c0, ldo, mc ? mc + r * ldm : nullptr, ldm);
    for (; r < rows; ++r)
      tile<1, CV, E>(in + r * rs, rs, ks, K, w + c0, ldw, ic ? ic + r * ldi : nullptr, ldi,
                     out + r * ldo + c0, ldo, mc ? mc + r * ldm : nullptr, ldm);
  }
}

// Sum of the lanes of v.
static inline float lane_sum(vf v) {
  float s = 0.f;
  for (int i = 0; i < W; ++i) s += v[i];
  return s;
}

template <int D>
static void forward_block(const MlpArgs& a, int64_t p0, int rows) {
  constexpr int H = kMlpHidden;
  const float* code = a.code + p0 * D;
  const float* sh = a.sh + p0 * kMlpDir;
  float* h1 = a.h1 + p0 * H;
  float* h2 = a.h2 + p0 * H;
  float* h3 = a.h3 + p0 * H;
  product<H, kRelu>(rows, code, D, 1, D, a.w0t, H, nullptr, 0, h1, H);
  product<H, kRelu>(rows, h1, H, 1, H, a.w1t, H, nullptr, 0, h2, H);
  product<H, kPlain>(rows, sh, kMlpDir, 1, kMlpDir, a.wdt, H, nullptr, 0, h3, H);
  product<H, kRelu>(rows, h2, H, 1, H, a.mt, H, h3, H, h3, H);
  for (int r = 0; r < rows; ++r) {
    const float* h = h3 + r * H;
    for (int c = 0; c < 3; ++c) {
      vf acc = vf{};
      for (int v = 0; v < H / W; ++v) acc = fmadd(load(h + v * W), load(a.w2 + c * H + v * W), acc);
      const float s = 1.f / (1.f + std::exp(-lane_sum(acc)));
      a.s[(p0 + r) * 3 + c] = s;
      a.out[(p0 + r) * 3 + c] = s * a.scale - a.shift;
    }
  }
}

// Backward of one block: input gradients written, weight gradients added into g (the chunk's
// sums). scratch holds kBlock * (3 + 3 * H) floats.
template <int D>
static void backward_block(const MlpArgs& a, int64_t p0, int rows, const MlpGrads& g,
                           float* scratch) {
  constexpr int H = kMlpHidden;
  const float* code = a.code + p0 * D;
  const float* sh = a.sh + p0 * kMlpDir;
  const float* h1 = a.h1 + p0 * H;
  const float* h2 = a.h2 + p0 * H;
  const float* h3 = a.h3 + p0 * H;
  float* go = scratch;                   // (rows, 3): d loss / d (pre-sigmoid output)
  float* gpre = go + kMlpBlock * 3;      // (rows, H): d loss / d (colour head's hidden pre-act)
  float* gh2 = gpre + kMlpBlock * H;     // (rows, H)
  float* gh1 = gh2 + kMlpBlock * H;      // (rows, H)
  for (int r = 0; r < rows * 3; ++r) {
    const float s = a.s[p0 * 3 + r];
    go[r] = a.grad[p0 * 3 + r] * a.scale * s * (1.f - s);
  }
  product<H, kPlain>(3, go, 1, 3, rows, h3, H, g.w2, H, g.w2, H);
  product<H, kWherePositive>(rows, go, 3, 1, 3, a.w2, H, nullptr, 0, gpre, H, h3, H);
  product<H, kPlain>(H, gpre, 1, H, rows, h2, H, g.m, H, g.m, H);
  product<kMlpDir, kPlain>(H, gpre, 1, H, rows, sh, kMlpDir, g.wd, kMlpDir, g.wd, kMlpDir);
  product<kMlpDir, kPlain>(rows, gpre, H, 1, H, a.wd, kMlpDir, nullptr, 0,
                           a.g_sh + p0 * kMlpDir, kMlpDir);
  product<H, kWherePositive>(rows, gpre, H, 1, H, a.m, H, nullptr, 0, gh2, H, h2, H);
  product<H, kPlain>(H, gh2, 1, H, rows, h1, H, g.w1, H, g.w1, H);
  product<H, kWherePositive>(rows, gh2, H, 1, H, a.w1, H, nullptr, 0, gh1, H, h1, H);
  product<D, kPlain>(H, gh1, 1, H, rows, code, D, g.w0, D, g.w0, D);
  product<D, kPlain>(rows, gh1, H, 1, H, a.w0, D, nullptr, 0, a.g_code + p0 * D, D);
}

template <int D>
static void forward_range_d(const MlpArgs& a, int64_t begin, int64_t end) {
  for (int64_t p = begin; p < end; p += kMlpBlock)
    forward_block<D>(a, p, (int)(end - p < kMlpBlock ? end - p : kMlpBlock));
}

template <int D>
static void backward_range_d(const MlpArgs& a, int64_t begin, int64_t end, const MlpGrads& g,
                             float* scratch) {
  for (int64_t p = begin; p < end; p += kMlpBlock)
    backward_block<D>(a, p, (int)(end - p < kMlpBlock ? end - p : kMlpBlock), g, scratch);
}

void mlp_forward_range(const MlpArgs& a, int64_t begin, int64_t end) {
  switch (a.code_dim) {
    case 16: return forward_range_d<16>(a, begin, end);
    case 32: return forward_range_d<32>(a, begin, end);
    default: return forward_range_d<64>(a, begin, end);  // mlp.cpp admits 16, 32 and 64 only
  }
}

void mlp_backward_range(const MlpArgs& a, int64_t begin, int64_t end, const MlpGrads& g,
                        float* scratch) {
  switch (a.code_dim) {
    case 16: return backward_range_d<16>(a, begin, end, g, scratch);
    case 32: return backward_range_d<32>(a, begin, end, g, scratch);
    default: return backward_range_d<64>(a, begin, end, g, scratch);
  }
}

}  // namespace MLP_NS
