// Warp-consistency L1 (engine/train/consistency.py, warp_consistency_loss) in one pass: each
// reference pixel is lifted with its rendered depth, projected into the source camera, masked
// (alpha, in front, inside, optionally not occluded in the source's depth) and compared with the
// source photo sampled bilinearly there. The loss is a mean over the pixels that pass, so the
// forward also writes each pixel's gradient numerator with respect to its depth and alpha; the
// autograd wrapper (native.py) only scales them by upstream / count.
//
// The sampling follows torch's grid_sample (align_corners=False, border padding): pixel centres
// at +0.5, so the sample column is u - 0.5; corners past the last column or row add nothing.
// Arithmetic is float32 in the torch implementation's order where it matters for the masks; the
// loss sum is double, per row, then over rows in order (the same for any thread count).
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <cmath>
#include <vector>

namespace {

struct Intrinsics {
  float fx, fy, cx, cy;
};

Intrinsics intrinsics(const std::vector<double>& k, const char* name) {
  TORCH_CHECK(k.size() == 4, name, ": expected (fx, fy, cx, cy)");
  return {(float)k[0], (float)k[1], (float)k[2], (float)k[3]};
}

void check_map(const torch::Tensor& t, const char* name, int64_t h, int64_t w) {
  TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == torch::kFloat32 && t.is_contiguous(),
              name, ": expected a contiguous float32 CPU tensor");
  TORCH_CHECK(t.dim() == 2 && t.size(0) == h && t.size(1) == w, name, ": expected (", h, ", ",
              w, "), got ", t.sizes());
}

void check_image(const torch::Tensor& t, const char* name) {
  TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == torch::kFloat32 && t.is_contiguous(),
              name, ": expected a contiguous float32 CPU tensor");
  TORCH_CHECK(t.dim() == 3 && t.size(0) == 3, name, ": expected (3, H, W), got ", t.sizes());
}

}  // namespace

// Returns (loss as sum / count or 0, count, d sum / d depth, d sum / d alpha); the gradients
// are undefined unless need_grad (the alpha one also unless alpha is given).
std::vector<torch::Tensor> warp_l1_forward(torch::Tensor depth, c10::optional<torch::Tensor> alpha,
                                           torch::Tensor ref_image, torch::Tensor src_image,
                                           c10::optional<torch::Tensor> src_depth,
                                           std::vector<double> ref_k, std::vector<double> src_k,
                                           std::vector<double> rot, std::vector<double> trans,
                                           double min_alpha, double tolerance, bool need_grad) {
  check_image(ref_image, "reference image");
  check_image(src_image, "source image");
  const int64_t H = ref_image.size(1), W = ref_image.size(2);
  const int64_t Hs = src_image.size(1), Ws = src_image.size(2);
  check_map(depth, "depth", H, W);
  const bool has_alpha = alpha.has_value() && alpha->defined();
  if (has_alpha) check_map(*alpha, "alpha", H, W);
  const bool has_sd = src_depth.has_value() && src_depth->defined();
  if (has_sd) check_map(*src_depth, "source depth", Hs, Ws);
  TORCH_CHECK(rot.size() == 9 && trans.size() == 3, "pose: expected 9 rotation and 3 translation values");
  const Intrinsics kr = intrinsics(ref_k, "reference intrinsics");
  const Intrinsics ks = intrinsics(src_k, "source intrinsics");
  float R[9], t[3];
  for (int i = 0; i < 9; ++i) R[i] = (float)rot[i];
  for (int i = 0; i < 3; ++i) t[i] = (float)trans[i];
  const float amin = (float)min_alpha, tol = (float)tolerance;
  const float u_hi = (float)Ws - 0.5f, v_hi = (float)Hs - 0.5f;

  torch::Tensor gd, ga;
  if (need_grad) {
    gd = torch::zeros({H, W}, depth.options());
    if (has_alpha) ga = torch::zeros({H, W}, depth.options());
  }
  std::vector<double> row_sum(H, 0.0);
  std::vector<int64_t> row_count(H, 0);
  const float* pd = depth.data_ptr<float>();
  const float* pa = has_alpha ? alpha->data_ptr<float>() : nullptr;
  const float* pr = ref_image.data_ptr<float>();
  const float* ps = src_image.data_ptr<float>();
  const float* psd = has_sd ? src_depth->data_ptr<float>() : nullptr;
  float* pgd = need_grad ? gd.data_ptr<float>() : nullptr;
  float* pga = need_grad && has_alpha ? ga.data_ptr<float>() : nullptr;
  const int64_t plane = Hs * Ws;

  at::parallel_for(0, H, 8, [&](int64_t y_lo, int64_t y_hi) {
    for (int64_t y = y_lo; y < y_hi; ++y) {
      double sum = 0.0;
      int64_t count = 0;
      const float ry = ((float)y + 0.5f - kr.cy) / kr.fy;
      for (int64_t x = 0; x < W; ++x) {
        const int64_t p = y * W + x;
        const float d = pd[p];
        float a = 1.f, z;
        bool valid;
        if (pa) {
          a = pa[p];
          valid = a >= amin && std::isfinite(d);
          z = d / (valid ? a : 1.f);
        } else {
          valid = std::isfinite(d);
          z = d;
        }
        valid = valid && z > 0.f;
        if (!valid) continue;
        const float rx = ((float)x + 0.5f - kr.cx) / kr.fx;
        const float p0 = rx * z, p1 = ry * z, p2 = z;  // the view-space point
        const float qx = R[0] * p0 + R[1] * p1 + R[2] * p2 + t[0];
        const float qy = R[3] * p0 + R[4] * p1 + R[5] * p2 + t[1];
        const float qz = R[6] * p0 + R[7] * p1 + R[8] * p2 + t[2];
        if (!(qz > 1e-12f)) continue;  // behind the source (or on its plane)
        const float u = ks.fx * qx / qz + ks.cx;
        const float v = ks.fy * qy / qz + ks.cy;
        if (!(u >= 0.5f && u <= u_hi && v >= 0.5f && v <= v_hi)) continue;
        const float ix = u - 0.5f, iy = v - 0.5f;  // in [0, Ws - 1] x [0, Hs - 1]
        if (psd) {
          const int64_t nx = (int64_t)std::nearbyint(ix), ny = (int64_t)std::nearbyint(iy);
          const float seen = psd[ny * Ws + nx];
          const bool empty = !std::isfinite(seen) || seen <= 0.f;
          if (!(empty || std::fabs(qz - seen) <= tol * qz)) continue;  // occluded there
        }
        const int64_t x0 = (int64_t)std::floor(ix), y0 = (int64_t)std::floor(iy);
        const float wx = ix - (float)x0, wy = iy - (float)y0;
        const bool x1_in = x0 + 1 < Ws, y1_in = y0 + 1 < Hs;
        float l = 0.f, dl_dix = 0.f, dl_diy = 0.f;
        for (int c = 0; c < 3; ++c) {
          const float* img = ps + c * plane;
          const float v00 = img[y0 * Ws + x0];
          const float v01 = x1_in ? img[y0 * Ws + x0 + 1] : 0.f;
          const float v10 = y1_in ? img[(y0 + 1) * Ws + x0] : 0.f;
          const float v11 = x1_in && y1_in ? img[(y0 + 1) * Ws + x0 + 1] : 0.f;
          const float s = (1.f - wy) * ((1.f - wx) * v00 + wx * v01) +
                          wy * ((1.f - wx) * v10 + wx * v11);
          const float diff = s - pr[c * H * W + p];
          l += std::fabs(diff);
          const float sg = (diff > 0.f) - (diff < 0.f);  // |.|' with 0 at 0, as torch
          dl_dix += sg * ((1.f - wy) * (v01 - v00) + wy * (v11 - v10));
          dl_diy += sg * ((1.f - wx) * (v10 - v00) + wx * (v11 - v01));
        }
        sum += (double)(l / 3.f);
        ++count;
        if (!pgd) continue;
        // u = fx qx / qz + cx with q = z (R ray) + t: du/dz = fx (Rr_x qz - qx Rr_z) / qz^2.
        const float rrx = R[0] * rx + R[1] * ry + R[2];
        const float rry = R[3] * rx + R[4] * ry + R[5];
        const float rrz = R[6] * rx + R[7] * ry + R[8];
        const float iqz2 = 1.f / (qz * qz);
        const float du_dz = ks.fx * (rrx * qz - qx * rrz) * iqz2;
        const float dv_dz = ks.fy * (rry * qz - qy * rrz) * iqz2;
        const float dl_dz = (dl_dix * du_dz + dl_diy * dv_dz) / 3.f;
        if (pga) {
          pgd[p] = dl_dz / a;       // z = d / a
          pga[p] = -dl_dz * z / a;  // dz/da = -d / a^2
        } else {
          pgd[p] = dl_dz;
        }
      }
      row_sum[y] = sum;
      row_count[y] = count;
    }
  });
  double sum = 0.0;
  int64_t count = 0;
  for (int64_t y = 0; y < H; ++y) {
    sum += row_sum[y];
    count += row_count[y];
  }
  auto loss = torch::tensor(count ? (float)(sum / (double)count) : 0.f, depth.options());
  auto n = torch::tensor(count, torch::TensorOptions().dtype(torch::kInt64));
  return {loss, n, gd, ga};
}
