// Fused degree-3 real spherical harmonics (16 values, the 3DGS basis = torch-ngp's "degree 4"
// direction encoding) and its gradient w.r.t. the direction. The torch version in
// engine/color/sh.py is ~90 small element-wise ops forward and more backward; this is one pass.
#include <torch/extension.h>
#include <ATen/Parallel.h>



namespace {

constexpr float C0 = 0.28209479177387814f;
constexpr float C1 = 0.4886025119029199f;
constexpr float C2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f,
                         -1.0925484305920792f, 0.5462742152960396f};
constexpr float C3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f,
                         0.3731763325901154f, -0.4570457994644658f, 1.445305721320277f,
                         -0.5900435899266435f};

void check_dirs(const torch::Tensor& d) {
  TORCH_CHECK(d.device().is_cpu() && d.scalar_type() == torch::kFloat32 && d.dim() == 2 &&
                  d.size(1) == 3 && d.is_contiguous(),
              "dirs: expected a contiguous float32 CPU tensor of shape (N, 3), got ", d.sizes());
}

// Direction i of an (N, 3) array and the products of its coordinates both passes read.
struct Dir {
  float x, y, z, xx, yy, zz, xy, yz, xz;
};

// Calls f(i, dir) for every direction of the checked (N, 3) dirs, in parallel.
template <typename F>
void for_each_dir(const torch::Tensor& dirs, F f) {
  const float* d = dirs.data_ptr<float>();
  at::parallel_for(0, dirs.size(0), 4096, [&](int64_t lo, int64_t hi) {
    for (int64_t i = lo; i < hi; ++i) {
      const float x = d[3 * i], y = d[3 * i + 1], z = d[3 * i + 2];
      f(i, Dir{x, y, z, x * x, y * y, z * z, x * y, y * z, x * z});
    }
  });
}

}  // namespace

torch::Tensor sh16_forward(torch::Tensor dirs) {
  check_dirs(dirs);
  const int64_t n = dirs.size(0);
  auto out = torch::empty({n, 16}, dirs.options());
  float* o = out.data_ptr<float>();
  for_each_dir(dirs, [&](int64_t i, const Dir& dir) {
    const auto [x, y, z, xx, yy, zz, xy, yz, xz] = dir;
    float* r = o + 16 * i;
    r[0] = C0;
    r[1] = -C1 * y;
    r[2] = C1 * z;
    r[3] = -C1 * x;
    r[4] = C2[0] * xy;
    r[5] = C2[1] * yz;
    r[6] = C2[2] * (2.f * zz - xx - yy);
    r[7] = C2[3] * xz;
    r[8] = C2[4] * (xx - yy);
    r[9] = C3[0] * y * (3.f * xx - yy);
    r[10] = C3[1] * xy * z;
    r[11] = C3[2] * y * (4.f * zz - xx - yy);
    r[12] = C3[3] * z * (2.f * zz - 3.f * xx - 3.f * yy);
    r[13] = C3[4] * x * (4.f * zz - xx - yy);
    r[14] = C3[5] * z * (xx - yy);
    r[15] = C3[6] * x * (xx - 3.f * yy);
  });
  return out;
}

torch::Tensor sh16_backward(torch::Tensor dirs, torch::Tensor grad) {
  check_dirs(dirs);
  const int64_t n = dirs.size(0);
  TORCH_CHECK(grad.scalar_type() == torch::kFloat32 && grad.dim() == 2 && grad.size(0) == n &&
                  grad.size(1) == 16 && grad.is_contiguous(),
              "grad: expected a contiguous float32 tensor of shape (N, 16), got ", grad.sizes());
  auto out = torch::empty({n, 3}, dirs.options());
  const float* g = grad.data_ptr<float>();
  float* o = out.data_ptr<float>();
  for_each_dir(dirs, [&](int64_t i, const Dir& dir) {
    const auto [x, y, z, xx, yy, zz, xy, yz, xz] = dir;
    const float* q = g + 16 * i;
    // Partial derivatives of each basis function, accumulated band by band.
    float gx = -C1 * q[3];
    float gy = -C1 * q[1];
    float gz = C1 * q[2];
    gx += C2[0] * y * q[4] - 2.f * C2[2] * x * q[6] + C2[3] * z * q[7] + 2.f * C2[4] * x * q[8];
    gy += C2[0] * x * q[4] + C2[1] * z * q[5] - 2.f * C2[2] * y * q[6] - 2.f * C2[4] * y * q[8];
    gz += C2[1] * y * q[5] + 4.f * C2[2] * z * q[6] + C2[3] * x * q[7];
    gx += C3[0] * 6.f * xy * q[9] + C3[1] * yz * q[10] - C3[2] * 2.f * xy * q[11] -
          C3[3] * 6.f * xz * q[12] + C3[4] * (4.f * zz - 3.f * xx - yy) * q[13] +
          C3[5] * 2.f * xz * q[14] + C3[6] * 3.f * (xx - yy) * q[15];
    gy += C3[0] * 3.f * (xx - yy) * q[9] + C3[1] * xz * q[10] +
          C3[2] * (4.f * zz - xx - 3.f * yy) * q[11] - C3[3] * 6.f * yz * q[12] -
          C3[4] * 2.f * xy * q[13] - C3[5] * 2.f * yz * q[14] - C3[6] * 6.f * xy * q[15];
    gz += C3[1] * xy * q[10] + C3[2] * 8.f * yz * q[11] +
          C3[3] * (6.f * zz - 3.f * xx - 3.f * yy) * q[12] + C3[4] * 8.f * xz * q[13] +
          C3[5] * (xx - yy) * q[14];
    o[3 * i] = gx;
    o[3 * i + 1] = gy;
    o[3 * i + 2] = gz;
  });
  return out;
}
