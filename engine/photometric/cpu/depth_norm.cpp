// Native CPU patch-normalized depth loss (DNGaussian's Global-Local Depth Normalization term),
// value and gradient with respect to the rendered depth in one call; the definition it restates
// is engine/losses.py depth_norm_loss (read that first), the Python side engine/photometric/
// native.py.
//
// For a rendered depth D (H, W), a patch size p and the prior's normalized patches t (P, n):
//   v_ki   the n = p^2 values of patch k (non-overlapping tiles from the top-left corner; the last
//          H mod p rows and W mod p columns are left out), P = (H / p) (W / p), N = P n;
//   c_ki = v_ki - mean_i v_ki;  s_k = sqrt(max(sum_i c_ki^2 / (n - 1), 1e-30))   (local mode)
//          or the detached std of all of D (global mode, the same floor);
//   e_ki = v_ki - mean_ki v_ki; sigma = sqrt(max(sum e^2 / (N - 1), 1e-30));
//   eps = max(0.01 sigma, floor);  x_ki = c_ki / (s_k + eps);  r = x - t;
//   L = sum_{|r| > margin} r^2 / #{|r| > margin}   (0, with a zero gradient, when none).
// Backward, with g = 2 r [|r| > margin] / count and S_k = s_k + eps:
//   dL/dc_ki = g_ki / S_k + G_k c_ki / ((n - 1) s_k) [local, unfloored],  G_k = -sum_i g c / S_k^2
//   dL/de_ki = (sum_k G_k) 0.01 e_ki / ((N - 1) sigma)                     [eps unfloored]
//   and each of the two centrings subtracts its mean: dL/dv = dc - mean_i dc + de - mean de.
// Sums run in double; the per-value arithmetic in float, as the torch version's. Patches are
// split between threads in fixed blocks and the block sums added in block order, so the result
// does not depend on the thread count.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

constexpr double kVarFloor = 1e-30;  // engine/losses.py _std
constexpr int64_t kPatchesPerBlock = 64;

struct Grid {
  int64_t h, w, p, cols, patches, n;
  // f(i, j) for the values of patch k: i its index in the patch (row-major), j the pixel's.
  template <class F>
  void each(int64_t k, F f) const {
    const int64_t row0 = (k / cols) * p, col0 = (k % cols) * p;
    for (int64_t a = 0; a < p; ++a) {
      const int64_t j0 = (row0 + a) * w + col0, i0 = a * p;
      for (int64_t b = 0; b < p; ++b) f(i0 + b, j0 + b);
    }
  }
};

// Sum over blocks of patches of f(k) (a double), in block order.
template <class F>
double block_sum(int64_t patches, F f) {
  const int64_t blocks = (patches + kPatchesPerBlock - 1) / kPatchesPerBlock;
  std::vector<double> part(blocks, 0.0);
  at::parallel_for(0, blocks, 1, [&](int64_t lo, int64_t hi) {
    for (int64_t b = lo; b < hi; ++b) {
      double acc = 0.0;
      const int64_t end = std::min(patches, (b + 1) * kPatchesPerBlock);
      for (int64_t k = b * kPatchesPerBlock; k < end; ++k) acc += f(k);
      part[b] = acc;
    }
  });
  double total = 0.0;
  for (double v : part) total += v;
  return total;
}

// std with the floor of engine/losses.py _std, of values whose centred squares sum to `sq`.
double floored_std(double sq, int64_t count) {
  if (count < 2) return 0.0;
  return std::sqrt(std::max(sq / double(count - 1), kVarFloor));
}

}  // namespace

// Returns {loss (0-dim float32), d loss / d depth (H, W) or an undefined tensor}.
std::vector<torch::Tensor> depth_norm_forward(torch::Tensor depth, torch::Tensor target,
                                              int64_t patch, double margin, bool global_mode,
                                              double std_floor, bool need_grad) {
  TORCH_CHECK(depth.device().is_cpu() && depth.scalar_type() == torch::kFloat32 &&
                  depth.dim() == 2 && depth.is_contiguous(),
              "depth: expected a contiguous float32 (H, W) CPU tensor");
  const int64_t h = depth.size(0), w = depth.size(1);
  TORCH_CHECK(patch >= 1 && patch <= std::min(h, w), "patch: expected 1..min(H, W), got ", patch);
  Grid g{h, w, patch, w / patch, (h / patch) * (w / patch), patch * patch};
  TORCH_CHECK(target.device().is_cpu() && target.scalar_type() == torch::kFloat32 &&
                  target.dim() == 2 && target.size(0) == g.patches && target.size(1) == g.n &&
                  target.is_contiguous(),
              "target: expected contiguous float32 (", g.patches, ", ", g.n, "), got ",
              target.sizes());
  const float* d = depth.data_ptr<float>();
  const float* t = target.data_ptr<float>();
  const int64_t P = g.patches, n = g.n, N = P * n;

  // Per-patch mean, local std; the mean over all patch values.
  std::vector<float> mean(P), scale(P);
  std::vector<uint8_t> scale_live(P, 0);  // the local std's floor not reached: it has a gradient
  const double total = block_sum(P, [&](int64_t k) {
    double s = 0.0;
    g.each(k, [&](int64_t, int64_t j) { s += d[j]; });
    mean[k] = float(s / double(n));
    return s;
  });
  const float mean_all = float(total / double(N));
  double global_scale = 0.0;
  if (global_mode) {  // std of the whole map (not only the patches), no gradient
    double s = 0.0;
    for (int64_t j = 0; j < h * w; ++j) s += d[j];
    const float m = float(s / double(h * w));
    double sq = 0.0;
    for (int64_t j = 0; j < h * w; ++j) sq += double(d[j] - m) * double(d[j] - m);
    global_scale = floored_std(sq, h * w);
  }
  const double sq_all = block_sum(P, [&](int64_t k) {
    double sq_k = 0.0, sq_e = 0.0;
    g.each(k, [&](int64_t, int64_t j) {
      const double c = double(d[j] - mean[k]), e = double(d[j] - mean_all);
      sq_k += c * c;
      sq_e += e * e;
    });
    if (global_mode) {
      scale[k] = float(global_scale);
    } else {
      scale[k] = float(floored_std(sq_k, n));
      scale_live[k] = n >= 2 && sq_k / double(n - 1) >= kVarFloor;
    }
    return sq_e;
  });
  const double sigma = floored_std(sq_all, N);
  const bool sigma_live = N >= 2 && sq_all / double(N - 1) >= kVarFloor;
  const double eps_raw = 0.01 * sigma;
  const float eps = float(std::max(eps_raw, std_floor));
  const bool eps_live = sigma_live && eps_raw >= std_floor;

  // Residuals past the margin: their count and squared sum.
  std::vector<int64_t> kept_per_patch(P, 0);
  const double sq_kept = block_sum(P, [&](int64_t k) {
    const float inv = 1.0f / (scale[k] + eps);
    double s = 0.0;
    int64_t kept = 0;
    g.each(k, [&](int64_t i, int64_t j) {
      const float r = (d[j] - mean[k]) * inv - t[k * n + i];
      if (std::fabs(r) > margin) {
        s += double(r) * double(r);
        ++kept;
      }
    });
    kept_per_patch[k] = kept;
    return s;
  });
  int64_t count = 0;
  for (int64_t c : kept_per_patch) count += c;
  auto loss = torch::zeros({}, torch::kFloat32);
  if (count > 0) loss.fill_(sq_kept / double(count));
  torch::Tensor grad;
  if (!need_grad) return {loss, grad};
  grad = torch::zeros({h, w}, torch::kFloat32);
  if (count == 0) return {loss, grad};
  float* gd = grad.data_ptr<float>();
  const double two_over_count = 2.0 / double(count);

  // Direct and local-std paths per patch (each pixel belongs to one patch: no write conflicts);
  // G_k collected for the epsilon path.
  std::vector<double> big_g(P, 0.0);
  at::parallel_for(0, P, kPatchesPerBlock, [&](int64_t lo, int64_t hi) {
    std::vector<double> dc(n);
    for (int64_t k = lo; k < hi; ++k) {
      const double sk = double(scale[k]) + double(eps);
      const float inv = 1.0f / (scale[k] + eps);
      double sum_gc = 0.0;
      g.each(k, [&](int64_t i, int64_t j) {
        const float c = d[j] - mean[k];
        const float r = c * inv - t[k * n + i];
        const double gx = std::fabs(r) > margin ? two_over_count * double(r) : 0.0;
        dc[i] = gx;
        sum_gc += gx * double(c);
      });
      const double gk = -sum_gc / (sk * sk);
      big_g[k] = gk;
      const double local = !global_mode && scale_live[k]
                               ? gk / (double(n - 1) * double(scale[k]))
                               : 0.0;
      double mean_dc = 0.0;
      g.each(k, [&](int64_t i, int64_t j) {
        dc[i] = dc[i] / sk + local * double(d[j] - mean[k]);
        mean_dc += dc[i];
      });
      mean_dc /= double(n);
      g.each(k, [&](int64_t i, int64_t j) { gd[j] = float(dc[i] - mean_dc); });
    }
  });
  if (eps_live) {
    double sum_g = 0.0;
    for (double v : big_g) sum_g += v;
    const double coef = sum_g * 0.01 / (double(N - 1) * sigma);
    // mean of coef * e over all values: sum e is ~0 but is taken exactly.
    const double sum_e = block_sum(P, [&](int64_t k) {
      double s = 0.0;
      g.each(k, [&](int64_t, int64_t j) { s += double(d[j] - mean_all); });
      return s;
    });
    const double shift = coef * sum_e / double(N);
    at::parallel_for(0, P, kPatchesPerBlock, [&](int64_t lo, int64_t hi) {
      for (int64_t k = lo; k < hi; ++k)
        g.each(k, [&](int64_t, int64_t j) {
          gd[j] = float(double(gd[j]) + coef * double(d[j] - mean_all) - shift);
        });
    });
  }
  return {loss, grad};
}
