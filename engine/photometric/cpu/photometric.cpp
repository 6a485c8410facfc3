// Native CPU photometric loss: L1 + lambda * (1 - SSIM) of a predicted (C, H, W) image against
// its target, value and gradient with respect to the prediction in one call. The Python side
// (engine/photometric/native.py) wraps it in a torch.autograd.Function whose backward scales the
// saved gradient by the upstream scalar.
//
// SSIM is 3DGS's training SSIM: a separable Gaussian window (1-D weights from Python, any odd
// size), zero padding, mean over pixels and channels. Per channel, with B the blur:
//   m = B(x), P = B(x*x), Q = B(x*y), sxx = P - m^2, sxy = Q - m*mu_y (mu_y, var_y: the
//   target's precomputed blurred mean and variance),
//   A1 = 2 m mu_y + C1, A2 = 2 sxy + C2, B1 = m^2 + mu_y^2 + C1, B2 = sxx + var_y + C2,
//   S = A1 A2 / (B1 B2).
// Gradient: S depends on x only through the three blurred maps m, P, Q, with per-pixel partials
//   dS/dm = 2 / (B1 B2) * (mu_y (A2 - A1) - m S (B2 - B1))
//   dS/dP = -S / B2
//   dS/dQ = 2 A1 / (B1 B2)
// and since the window is symmetric, the adjoint of the zero-padded blur is the same blur, so
//   d mean(S) / dx = (B(dS/dm) + 2 x B(dS/dP) + y B(dS/dQ)) / N.
// The L1 term adds sign(x - target) / N (sign(0) = 0, like torch's abs).
//
// Work plan: phase 1 runs over (channel, row) tasks: the vertical pass of x, x^2 and x*y for that
// row (11 input rows, 8 pixels of the row at a time), the horizontal pass of the three, the
// per-pixel SSIM and its partials, and at once the horizontal pass of the partials (stored as
// full maps). Phase 2, after a barrier, runs the vertical pass of those maps and writes the
// gradient row. Every output is computed by one thread in a fixed order, and the per-row sums
// are added in row order at the end, so the results do not depend on the thread count.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <omp.h>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

namespace {

int n_threads() { return std::max(1, at::get_num_threads()); }

// The 1-D window: `size` (odd) weights, radius = size / 2.
struct Window {
  const float* w;
  int size;
  int radius;
};

// Rows of the vertical pass that exist for output row i of an (H, W) plane: taps [t0, t1),
// tap t0 reading the plane's row that starts at offset `first`.
struct Taps {
  int t0, t1;
  int64_t first;
};
inline Taps tap_range(const Window& win, int64_t i, int64_t H, int64_t W) {
  const int t0 = (int)std::max<int64_t>(0, win.radius - i);
  const int t1 = (int)std::min<int64_t>(win.size, H - i + win.radius);
  return {t0, t1, (i + t0 - win.radius) * W};
}

// The blurs are written with AVX2 intrinsics (v8_* below), 8 pixels of a row at a time with all taps summed
// in a register (the compiler's version kept the row of sums in memory, a load and a store per
// tap). The scalar tails add the same products in the same tap order with the same FMAs, so a
// pixel's value does not depend on whether it fell in a vector or in the tail.
constexpr int64_t kLanes = 8;

// The 8-lane operations the blurs use: AVX2 intrinsics on x86; elsewhere GCC generic vectors
// (two q registers on aarch64's NEON) with fmaf lane by lane, fused as the intrinsic is.
#if defined(__x86_64__)
typedef __m256 v8;
inline v8 v8_zero() { return _mm256_setzero_ps(); }
inline v8 v8_set1(float x) { return _mm256_set1_ps(x); }
inline v8 v8_load(const float* p) { return _mm256_loadu_ps(p); }
inline void v8_store(float* p, v8 v) { _mm256_storeu_ps(p, v); }
inline v8 v8_mul(v8 a, v8 b) { return _mm256_mul_ps(a, b); }
inline v8 v8_fma(v8 a, v8 b, v8 c) { return _mm256_fmadd_ps(a, b, c); }
#else
typedef float v8 __attribute__((vector_size(32)));
inline v8 v8_zero() { return v8{}; }
inline v8 v8_set1(float x) { return v8{} + x; }
inline v8 v8_load(const float* p) {
  v8 v;
  __builtin_memcpy(&v, p, sizeof v);
  return v;
}
inline void v8_store(float* p, v8 v) { __builtin_memcpy(p, &v, sizeof v); }
inline v8 v8_mul(v8 a, v8 b) { return a * b; }
inline v8 v8_fma(v8 a, v8 b, v8 c) {
  v8 r;
  for (int l = 0; l < 8; ++l) r[l] = __builtin_fmaf(a[l], b[l], c[l]);
  return r;
}
#endif

// out[j] = sum_t w[t] * pad[j + t] for j < W, where pad holds the row at offset radius with
// `radius` zeros on either side (zero padding).
inline void horizontal(const float* __restrict pad, int64_t W, const Window& win,
                       float* __restrict out) {
  int64_t j = 0;
  for (; j + kLanes <= W; j += kLanes) {
    v8 acc = v8_zero();
    for (int t = 0; t < win.size; ++t) acc = v8_fma(v8_set1(win.w[t]), v8_load(pad + j + t), acc);
    v8_store(out + j, acc);
  }
  for (; j < W; ++j) {
    float acc = 0.f;
    for (int t = 0; t < win.size; ++t) acc = std::fma(win.w[t], pad[j + t], acc);
    out[j] = acc;
  }
}

// Vertical pass of row i of the (H, W) planes x and y: vx = B_v(x), vp = B_v(x*x) and
// vq = B_v(x*y). The products are rounded before weighting, as the torch reference
// blurs the stacked maps x, x*x, x*y.
inline void vertical_moments(const float* __restrict x, const float* __restrict y, int64_t H,
                             int64_t W, int64_t i, const Window& win, float* __restrict vx,
                             float* __restrict vp, float* __restrict vq) {
  const auto [t0, t1, first] = tap_range(win, i, H, W);
  int64_t j = 0;
  for (; j + kLanes <= W; j += kLanes) {
    v8 ax = v8_zero(), ap = ax, aq = ax;
    const float* xr = x + first + j;
    const float* yr = y + first + j;
    for (int t = t0; t < t1; ++t, xr += W, yr += W) {
      const v8 wt = v8_set1(win.w[t]);
      const v8 xv = v8_load(xr), yv = v8_load(yr);
      ax = v8_fma(wt, xv, ax);
      ap = v8_fma(wt, v8_mul(xv, xv), ap);
      aq = v8_fma(wt, v8_mul(xv, yv), aq);
    }
    v8_store(vx + j, ax);
    v8_store(vp + j, ap);
    v8_store(vq + j, aq);
  }
  for (; j < W; ++j) {
    float ax = 0.f, ap = 0.f, aq = 0.f;
    const float* xr = x + first + j;
    const float* yr = y + first + j;
    for (int t = t0; t < t1; ++t, xr += W, yr += W) {
      const float wt = win.w[t], xv = *xr;
      ax = std::fma(wt, xv, ax);
      ap = std::fma(wt, xv * xv, ap);
      aq = std::fma(wt, xv * *yr, aq);
    }
    vx[j] = ax;
    vp[j] = ap;
    vq[j] = aq;
  }
}

// Vertical pass of row i of three (H, W) planes at once (phase 2: the partials' maps).
inline void vertical3(const float* __restrict a, const float* __restrict b,
                      const float* __restrict c, int64_t H, int64_t W, int64_t i,
                      const Window& win, float* __restrict va, float* __restrict vb,
                      float* __restrict vc) {
  const auto [t0, t1, first] = tap_range(win, i, H, W);
  int64_t j = 0;
  for (; j + kLanes <= W; j += kLanes) {
    v8 sa = v8_zero(), sb = sa, sc = sa;
    int64_t off = first + j;
    for (int t = t0; t < t1; ++t, off += W) {
      const v8 wt = v8_set1(win.w[t]);
      sa = v8_fma(wt, v8_load(a + off), sa);
      sb = v8_fma(wt, v8_load(b + off), sb);
      sc = v8_fma(wt, v8_load(c + off), sc);
    }
    v8_store(va + j, sa);
    v8_store(vb + j, sb);
    v8_store(vc + j, sc);
  }
  for (; j < W; ++j) {
    float sa = 0.f, sb = 0.f, sc = 0.f;
    int64_t off = first + j;
    for (int t = t0; t < t1; ++t, off += W) {
      const float wt = win.w[t];
      sa = std::fma(wt, a[off], sa);
      sb = std::fma(wt, b[off], sb);
      sc = std::fma(wt, c[off], sc);
    }
    va[j] = sa;
    vb[j] = sb;
    vc[j] = sc;
  }
}

// Per pixel of a row: SSIM (into s) and its partials with respect to m, P and Q (into da, db,
// dc; see the top of the file). Separate, with restrict pointers, so that it vectorizes.
inline void ssim_partials(const float* __restrict m, const float* __restrict P,
                          const float* __restrict Q, const float* __restrict mu,
                          const float* __restrict var, int64_t W, float c1, float c2,
                          float* __restrict s, float* __restrict da, float* __restrict db,
                          float* __restrict dc) {
#pragma omp simd
  for (int64_t j = 0; j < W; ++j) {
    const float mx = m[j], my = mu[j];
    const float sxx = P[j] - mx * mx;
    const float sxy = Q[j] - mx * my;
    const float A1 = 2.f * mx * my + c1;
    const float A2 = 2.f * sxy + c2;
    const float B1 = mx * mx + my * my + c1;
    const float B2 = sxx + var[j] + c2;
    const float inv = 1.f / (B1 * B2);
    const float ssim = A1 * A2 * inv;
    s[j] = ssim;
    da[j] = 2.f * inv * (my * (A2 - A1) - mx * ssim * (B2 - B1));
    db[j] = -ssim / B2;
    dc[j] = 2.f * A1 * inv;
  }
}

// Per pixel of a row: the gradient sign(x - target) / N - lambda / N * (Ba + 2 x Bb + y Bc).
inline void gradient_row(const float* __restrict x, const float* __restrict target,
                         const float* __restrict y, const float* __restrict ba,
                         const float* __restrict bb, const float* __restrict bc, int64_t W,
                         float inv_n, float lam_n, float* __restrict g) {
#pragma omp simd
  for (int64_t j = 0; j < W; ++j) {
    const float d = x[j] - target[j];
    const float sign = (float)(d > 0.f) - (float)(d < 0.f);
    const float dssim = ba[j] + 2.f * x[j] * bb[j] + y[j] * bc[j];
    g[j] = sign * inv_n - lam_n * dssim;
  }
}

// Per-thread rows: padded (W + 2 radius, zero borders that are never written) and plain (W).
struct Scratch {
  std::vector<float> pad_x, pad_p, pad_q, row_m, row_p, row_q, row_s;
  Scratch(int64_t W, int radius) {
    const size_t padded = (size_t)(W + 2 * radius), plain = (size_t)std::max<int64_t>(W, 1);
    for (auto* v : {&pad_x, &pad_p, &pad_q}) v->assign(padded, 0.f);
    for (auto* v : {&row_m, &row_p, &row_q, &row_s}) v->assign(plain, 0.f);
  }
};

void check_image(const torch::Tensor& t, const char* name) {
  TORCH_CHECK(t.device().is_cpu(), name, ": expected a CPU tensor, got ", t.device());
  TORCH_CHECK(t.scalar_type() == torch::kFloat32, name, ": expected float32, got ",
              t.scalar_type());
  TORCH_CHECK(t.dim() == 3, name, ": expected shape (C, H, W), got ", t.sizes());
  TORCH_CHECK(t.is_contiguous(), name, ": expected a contiguous tensor");
}

void check_same_shape(const torch::Tensor& t, const torch::Tensor& like, const char* name) {
  check_image(t, name);
  TORCH_CHECK(t.sizes() == like.sizes(), name, ": expected shape ", like.sizes(), ", got ",
              t.sizes());
}

Window make_window(const torch::Tensor& weights) {
  TORCH_CHECK(weights.device().is_cpu() && weights.scalar_type() == torch::kFloat32 &&
                  weights.dim() == 1 && weights.is_contiguous(),
              "window: expected a contiguous float32 CPU vector, got ", weights.sizes());
  const int64_t size = weights.size(0);
  TORCH_CHECK(size % 2 == 1, "window: expected an odd number of weights, got ", size);
  return {weights.data_ptr<float>(), (int)size, (int)(size / 2)};
}

// Returns (loss as a float32 scalar, gradient d loss / d pred or an undefined tensor).
// target: the L1 target; image: the SSIM target y (the same image in the trainer); mu_y and
// var_y: its blurred mean and variance with this window.
std::vector<torch::Tensor> forward(torch::Tensor pred, torch::Tensor target, torch::Tensor image,
                                   torch::Tensor mu_y, torch::Tensor var_y,
                                   torch::Tensor weights, double lambda_dssim, double c1_d,
                                   double c2_d, bool need_grad) {
  check_image(pred, "pred");
  check_same_shape(target, pred, "target");
  check_same_shape(image, pred, "ssim image");
  check_same_shape(mu_y, pred, "ssim mean");
  check_same_shape(var_y, pred, "ssim variance");
  const Window win = make_window(weights);
  const int64_t C = pred.size(0), H = pred.size(1), W = pred.size(2);
  const int64_t plane = H * W, tasks = C * H, n = C * plane;
  TORCH_CHECK(n > 0, "pred: expected a non-empty image, got shape ", pred.sizes());
  const float c1 = (float)c1_d, c2 = (float)c2_d;
  const float inv_n = (float)(1.0 / (double)n);
  const float lam_n = (float)(lambda_dssim / (double)n);

  torch::Tensor grad, maps;
  if (need_grad) {
    grad = torch::empty_like(pred);
    maps = torch::empty({3, C, H, W}, pred.options());  // horizontal blurs of the partials
  }
  std::vector<double> s_rows((size_t)tasks), l1_rows((size_t)tasks);
  const float* px = pred.data_ptr<float>();
  const float* pt = target.data_ptr<float>();
  const float* py = image.data_ptr<float>();
  const float* pmu = mu_y.data_ptr<float>();
  const float* pvar = var_y.data_ptr<float>();
  float* pg = need_grad ? grad.data_ptr<float>() : nullptr;
  float* ha = need_grad ? maps.data_ptr<float>() : nullptr;
  float* hb = need_grad ? ha + n : nullptr;
  float* hc = need_grad ? hb + n : nullptr;

#pragma omp parallel num_threads(n_threads())
  {
    Scratch s(W, win.radius);
    float* bx = s.pad_x.data() + win.radius;
    float* bp = s.pad_p.data() + win.radius;
    float* bq = s.pad_q.data() + win.radius;
    float* m = s.row_m.data();
    float* P = s.row_p.data();
    float* Q = s.row_q.data();
    float* S = s.row_s.data();

#pragma omp for schedule(static)
    for (int64_t task = 0; task < tasks; ++task) {
      const int64_t c = task / H, i = task % H;
      const int64_t base = c * plane, row = base + i * W;
      vertical_moments(px + base, py + base, H, W, i, win, bx, bp, bq);
      horizontal(s.pad_x.data(), W, win, m);
      horizontal(s.pad_p.data(), W, win, P);
      horizontal(s.pad_q.data(), W, win, Q);
      const float* __restrict xr = px + row;
      const float* __restrict tr = pt + row;
      double l1 = 0.0;
#pragma omp simd reduction(+ : l1)
      for (int64_t j = 0; j < W; ++j) l1 += (double)std::fabs(xr[j] - tr[j]);
      // The partials overwrite the padded rows' interiors (x, x^2, x*y are used up).
      ssim_partials(m, P, Q, pmu + row, pvar + row, W, c1, c2, S, bx, bp, bq);
      double total = 0.0;
#pragma omp simd reduction(+ : total)
      for (int64_t j = 0; j < W; ++j) total += (double)S[j];
      s_rows[(size_t)task] = total;
      l1_rows[(size_t)task] = l1;
      if (need_grad) {
        horizontal(s.pad_x.data(), W, win, ha + row);
        horizontal(s.pad_p.data(), W, win, hb + row);
        horizontal(s.pad_q.data(), W, win, hc + row);
      }
    }
    // (implicit barrier: phase 2 reads rows of the maps that other threads wrote)
    if (need_grad) {
#pragma omp for schedule(static)
      for (int64_t task = 0; task < tasks; ++task) {
        const int64_t c = task / H, i = task % H;
        const int64_t base = c * plane, row = base + i * W;
        vertical3(ha + base, hb + base, hc + base, H, W, i, win, m, P, Q);
        gradient_row(px + row, pt + row, py + row, m, P, Q, W, inv_n, lam_n, pg + row);
      }
    }
  }

  double s_sum = 0.0, l1_sum = 0.0;
  for (int64_t t = 0; t < tasks; ++t) {
    s_sum += s_rows[(size_t)t];
    l1_sum += l1_rows[(size_t)t];
  }
  const double loss = l1_sum / (double)n + lambda_dssim * (1.0 - s_sum / (double)n);
  return {torch::tensor((float)loss, pred.options()).reshape({}), grad};
}

#if defined(__x86_64__)
std::string variant_name() { return "avx2"; }
#else
std::string variant_name() { return "portable"; }
#endif

}  // namespace

// Patch-normalized depth loss, depth_norm.cpp.
std::vector<torch::Tensor> depth_norm_forward(torch::Tensor depth, torch::Tensor target,
                                              int64_t patch, double margin, bool global_mode,
                                              double std_floor, bool need_grad);

// Warp-consistency L1, warp.cpp.
std::vector<torch::Tensor> warp_l1_forward(torch::Tensor depth, c10::optional<torch::Tensor> alpha,
                                           torch::Tensor ref_image, torch::Tensor src_image,
                                           c10::optional<torch::Tensor> src_depth,
                                           std::vector<double> ref_k, std::vector<double> src_k,
                                           std::vector<double> rot, std::vector<double> trans,
                                           double min_alpha, double tolerance, bool need_grad);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("warp_l1_forward", &warp_l1_forward,
        "Warp-consistency L1: (loss, count, d sum / d depth, d sum / d alpha; undefined unless "
        "asked)");
  m.def("depth_norm_forward", &depth_norm_forward,
        "Patch-normalized depth loss of a (H, W) depth: (loss, d loss / d depth or undefined)");
  m.def("forward", &forward,
        "L1 + lambda * (1 - SSIM) of (C, H, W) images: (loss, d loss / d pred or undefined)");
  m.def("variant", &variant_name, "Instruction-set level the extension was built for");
}
