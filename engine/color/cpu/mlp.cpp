// The colour field's fused MLPs (mlp_kernels.h): argument checks, the split of the points into
// chunks over the OpenMP threads, and the sum of the chunks' weight gradients. The Python side
// (engine/color/native.py) wraps forward/backward in a torch.autograd.Function; the torch
// version of the same function is engine/color/mlp.py.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <omp.h>

#include <algorithm>
#include <vector>

#include "common.h"

namespace {

using FwdFn = void (*)(const MlpArgs&, int64_t, int64_t);
using BwdFn = void (*)(const MlpArgs&, int64_t, int64_t, const MlpGrads&, float*);

#if defined(__x86_64__)
FwdFn forward_fn() {
  return use_avx512_kernels() ? avx512::mlp_forward_range : avx2::mlp_forward_range;
}
BwdFn backward_fn() {
  return use_avx512_kernels() ? avx512::mlp_backward_range : avx2::mlp_backward_range;
}
#else
FwdFn forward_fn() { return portable::mlp_forward_range; }
BwdFn backward_fn() { return portable::mlp_backward_range; }
#endif

void check(const torch::Tensor& t, const char* name, int64_t rows, int64_t cols) {
  TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == torch::kFloat32 && t.dim() == 2,
              name, ": expected a float32 CPU matrix, got ", t.scalar_type(), " ", t.sizes());
  TORCH_CHECK((rows < 0 || t.size(0) == rows) && t.size(1) == cols, name, ": expected shape (",
              rows < 0 ? std::string("N") : std::to_string(rows), ", ", cols, "), got ",
              t.sizes());
}

// Work is split into chunks of kChunk points, the same whatever the thread count: each chunk
// sums its own weight gradients and the chunks' sums are added in chunk order, so every result
// is the same for any number of threads.
constexpr int64_t kChunk = 16 * kMlpBlock;

int64_t chunks(int64_t n) { return (n + kChunk - 1) / kChunk; }

int n_threads(int64_t n) {
  return (int)std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), chunks(n)));
}

MlpArgs weights_args(const torch::Tensor& code, const torch::Tensor& sh, const torch::Tensor& w0,
                     const torch::Tensor& w1, const torch::Tensor& m, const torch::Tensor& wd,
                     const torch::Tensor& w2) {
  TORCH_CHECK(code.dim() == 2, "code: expected an (N, width) matrix, got ", code.sizes());
  const int64_t d = code.size(1);
  TORCH_CHECK(d == 16 || d == 32 || d == 64, "code: width ", d, " not supported (16, 32, 64)");
  check(code, "code", -1, d);
  check(sh, "sh", code.size(0), kMlpDir);
  check(w0, "w0", kMlpHidden, d);
  check(w1, "w1", kMlpHidden, kMlpHidden);
  check(m, "m", kMlpHidden, kMlpHidden);
  check(wd, "wd", kMlpHidden, kMlpDir);
  check(w2, "w2", 3, kMlpHidden);
  for (const auto* t : {&code, &sh, &w0, &w1, &m, &wd, &w2})
    TORCH_CHECK(t->is_contiguous(), "expected contiguous tensors");
  MlpArgs a{};
  a.code_dim = (int)d;
  a.code = code.data_ptr<float>();
  a.sh = sh.data_ptr<float>();
  a.w0 = w0.data_ptr<float>();
  a.w1 = w1.data_ptr<float>();
  a.m = m.data_ptr<float>();
  a.wd = wd.data_ptr<float>();
  a.w2 = w2.data_ptr<float>();
  return a;
}

}  // namespace

std::vector<torch::Tensor> mlp_forward(torch::Tensor code, torch::Tensor sh, torch::Tensor w0,
                                       torch::Tensor w1, torch::Tensor m, torch::Tensor wd,
                                       torch::Tensor w2, double scale, double shift) {
  code = code.contiguous(), sh = sh.contiguous(), w0 = w0.contiguous(), w1 = w1.contiguous();
  m = m.contiguous(), wd = wd.contiguous(), w2 = w2.contiguous();
  MlpArgs a = weights_args(code, sh, w0, w1, m, wd, w2);
  const int64_t n = code.size(0);
  // The forward multiplies by the transposes: (in, out) rows stream 64 outputs at a time.
  const torch::Tensor w0t = w0.t().contiguous(), w1t = w1.t().contiguous();
  const torch::Tensor mt = m.t().contiguous(), wdt = wd.t().contiguous();
  a.w0t = w0t.data_ptr<float>();
  a.w1t = w1t.data_ptr<float>();
  a.mt = mt.data_ptr<float>();
  a.wdt = wdt.data_ptr<float>();
  a.scale = (float)scale;
  a.shift = (float)shift;
  auto h1 = torch::empty({n, kMlpHidden}, code.options());
  auto h2 = torch::empty_like(h1), h3 = torch::empty_like(h1);
  auto s = torch::empty({n, 3}, code.options()), out = torch::empty_like(s);
  a.h1 = h1.data_ptr<float>();
  a.h2 = h2.data_ptr<float>();
  a.h3 = h3.data_ptr<float>();
  a.s = s.data_ptr<float>();
  a.out = out.data_ptr<float>();
  const FwdFn fwd = forward_fn();
  const int64_t nc = chunks(n);
#pragma omp parallel for schedule(static) num_threads(n_threads(n))
  for (int64_t c = 0; c < nc; ++c) fwd(a, c * kChunk, std::min(n, (c + 1) * kChunk));
  return {out, h1, h2, h3, s};
}

std::vector<torch::Tensor> mlp_backward(torch::Tensor grad, std::vector<torch::Tensor> saved,
                                        double scale) {
  TORCH_CHECK(saved.size() == 11, "saved: expected the 11 tensors of the forward");
  const auto& code = saved[0];
  MlpArgs a = weights_args(code, saved[1], saved[2], saved[3], saved[4], saved[5], saved[6]);
  const int64_t n = code.size(0), d = code.size(1);
  grad = grad.contiguous();
  check(grad, "grad", n, 3);
  for (int i = 7; i < 10; ++i) check(saved[i], "activation", n, kMlpHidden);
  check(saved[10], "s", n, 3);
  a.scale = (float)scale;
  a.h1 = saved[7].data_ptr<float>();
  a.h2 = saved[8].data_ptr<float>();
  a.h3 = saved[9].data_ptr<float>();
  a.s = saved[10].data_ptr<float>();
  a.grad = grad.data_ptr<float>();
  auto g_code = torch::empty({n, d}, code.options());
  auto g_sh = torch::empty({n, kMlpDir}, code.options());
  a.g_code = g_code.data_ptr<float>();
  a.g_sh = g_sh.data_ptr<float>();
  // Each chunk sums its points' weight gradients in a zeroed row of its own.
  const int64_t sizes[5] = {kMlpHidden * d, kMlpHidden * kMlpHidden, kMlpHidden * kMlpHidden,
                            kMlpHidden * kMlpDir, 3 * kMlpHidden};
  int64_t per_chunk = 0;
  for (int64_t s : sizes) per_chunk += s;
  const int64_t nc = chunks(n);
  auto sums = torch::zeros({std::max<int64_t>(nc, 1), per_chunk}, code.options());
  const BwdFn bwd = backward_fn();
#pragma omp parallel num_threads(n_threads(n))
  {
    std::vector<float> scratch(kMlpBlock * (3 + 3 * kMlpHidden));
#pragma omp for schedule(static)
    for (int64_t c = 0; c < nc; ++c) {
      float* base = sums.data_ptr<float>() + c * per_chunk;
      MlpGrads g{};
      g.w0 = base;
      g.w1 = g.w0 + sizes[0];
      g.m = g.w1 + sizes[1];
      g.wd = g.m + sizes[2];
      g.w2 = g.wd + sizes[3];
      bwd(a, c * kChunk, std::min(n, (c + 1) * kChunk), g, scratch.data());
    }
  }
  std::vector<torch::Tensor> out = {g_code, g_sh};
  const std::vector<std::vector<int64_t>> shapes = {
      {kMlpHidden, d}, {kMlpHidden, kMlpHidden}, {kMlpHidden, kMlpHidden},
      {kMlpHidden, kMlpDir}, {3, kMlpHidden}};
  const float* all = sums.data_ptr<float>();
  int64_t offset = 0;
  for (int i = 0; i < 5; ++i) {
    auto g = torch::empty(shapes[i], code.options());
    float* o = g.data_ptr<float>();
    // The chunks' sums added in chunk order.
    for (int64_t k = 0; k < sizes[i]; ++k) {
      float v = all[offset + k];
      for (int64_t c = 1; c < nc; ++c) v += all[c * per_chunk + offset + k];
      o[k] = v;
    }
    out.push_back(g);
    offset += sizes[i];
  }
  return out;
}
