// Native CPU hash-grid encoder: argument checks, the OpenMP loops over levels and point blocks,
// and the run-time choice of the per-ISA level kernels (kernels.h). The Python side
// (engine/color/native.py) wraps forward/backward in a torch.autograd.Function.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <omp.h>
#include <sys/mman.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <string>
#include <vector>

#include "common.h"

// Degree-3 SH direction encoding, sh.cpp.
torch::Tensor sh16_forward(torch::Tensor dirs);
torch::Tensor sh16_backward(torch::Tensor dirs, torch::Tensor grad);
// Flush-denormal mode of the compute threads, fpmode.cpp.
bool set_flush_denormal_all(bool on);
bool flush_denormal_enabled();
// The fused colour MLP, mlp.cpp.
std::vector<torch::Tensor> mlp_forward(torch::Tensor code, torch::Tensor sh, torch::Tensor w0,
                                       torch::Tensor w1, torch::Tensor m, torch::Tensor wd,
                                       torch::Tensor w2, double scale, double shift);
std::vector<torch::Tensor> mlp_backward(torch::Tensor grad, std::vector<torch::Tensor> saved,
                                        double scale);

#if defined(__x86_64__)
bool use_avx512_kernels() {
  static const bool use = [] {
    const char* force = std::getenv("SPARSESPLAT_HASHGRID_ISA");
    if (force && std::string(force) == "avx2") return false;
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
           __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl");
  }();
  return use;
}
#endif

namespace {

using LevelFn = void (*)(const LevelArgs&, int);

struct Variant {
  const char* name;
  LevelFn fwd;
  LevelFn bwd;
};

// The hash grid's level kernels for this CPU (use_avx512_kernels: common.h).
Variant pick_variant() {
#if defined(__x86_64__)
  if (use_avx512_kernels()) return {"avx512", avx512::forward_level, avx512::backward_level};
  return {"avx2", avx2::forward_level, avx2::backward_level};
#else
  return {"portable", portable::forward_level, portable::backward_level};
#endif
}

const Variant& variant() {
  static Variant v = pick_variant();
  return v;
}

// The dense table gradient is ~50 MB and is made every backward. From malloc that costs ~12k page
// faults and the kernel's zeroing of each page (~15 ms at 50k points); from fresh anonymous
// memory with transparent huge pages, ~25 faults that still zero 50 MB. So the gradient lives in
// a huge-page block that is recycled: when the tensor holding it is freed (the optimizer's
// zero_grad), its deleter puts the block back, and the next backward takes it and zeroes each
// level's rows inside the parallel level loop, in memory that is already mapped and warm.
struct GradBlock {
  void* base = nullptr;  // the mapping (len bytes)
  size_t len = 0;
  void* data = nullptr;  // 2 MB aligned start inside it
  size_t bytes = 0;      // the tensor's size
};

// Never destroyed (heap singletons): a tensor freed late in interpreter shutdown may still run
// its deleter after this library's static destructors would have run.
std::mutex& g_block_mutex = *new std::mutex;
std::vector<GradBlock>& g_free_blocks = *new std::vector<GradBlock>;  // ready for reuse
constexpr size_t kKeepBlocks = 1;  // the most blocks kept in g_free_blocks

void release_block(const GradBlock& b) {
  {
    std::lock_guard<std::mutex> lock(g_block_mutex);
    if (g_free_blocks.size() < kKeepBlocks) {
      g_free_blocks.push_back(b);
      return;
    }
  }
  munmap(b.base, b.len);
}

// Unmaps the kept blocks (a block in use is unmapped when its tensor is freed, as usual);
// returns the bytes unmapped.
int64_t release_cached_memory() {
  std::vector<GradBlock> kept;
  {
    std::lock_guard<std::mutex> lock(g_block_mutex);
    kept.swap(g_free_blocks);
  }
  int64_t bytes = 0;
  for (const GradBlock& k : kept) {
    munmap(k.base, k.len);
    bytes += (int64_t)k.len;
  }
  return bytes;
}

// A float32 (rows, cols) tensor in a huge-page block; *zeroed tells whether it is known to be
// all zeros (a fresh mapping) or holds a previous gradient (a recycled block). Returns an
// undefined tensor for small sizes or when mmap fails (the caller then uses torch::empty).
torch::Tensor grad_buffer(int64_t rows, int64_t cols, bool* zeroed) {
  constexpr size_t kHuge = size_t(2) << 20;
  const size_t bytes = size_t(rows) * size_t(cols) * sizeof(float);
  *zeroed = false;
  if (bytes < kHuge) return torch::Tensor();
  GradBlock b;
  std::vector<GradBlock> stale;  // kept blocks of another size: unmapped, not kept forever
  {
    std::lock_guard<std::mutex> lock(g_block_mutex);
    for (const GradBlock& k : g_free_blocks) {
      if (k.bytes == bytes && b.base == nullptr)
        b = k;
      else
        stale.push_back(k);
    }
    g_free_blocks.clear();
  }
  for (const GradBlock& k : stale) munmap(k.base, k.len);
  if (b.base == nullptr) {
    const size_t len = (bytes + kHuge - 1) / kHuge * kHuge + kHuge;  // room to align
    void* base = mmap(nullptr, len, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (base == MAP_FAILED) return torch::Tensor();
    char* aligned = reinterpret_cast<char*>(
        (reinterpret_cast<uintptr_t>(base) + kHuge - 1) / kHuge * kHuge);
    madvise(aligned, len - (aligned - static_cast<char*>(base)), MADV_HUGEPAGE);
    b = GradBlock{base, len, aligned, bytes};
    *zeroed = true;
  }
  return torch::from_blob(
      b.data, {rows, cols}, [b](void*) { release_block(b); },
      torch::TensorOptions().dtype(torch::kFloat32));
}

int n_threads() { return std::max(1, at::get_num_threads()); }

constexpr int64_t kPointsPerTask = 4096;  // forward work unit: one level x this many points

void check_tensor(const torch::Tensor& t, const char* name, int64_t cols) {
  TORCH_CHECK(t.device().is_cpu(), name, ": expected a CPU tensor, got ", t.device());
  TORCH_CHECK(t.scalar_type() == torch::kFloat32, name, ": expected float32, got ",
              t.scalar_type());
  TORCH_CHECK(t.dim() == 2 && t.size(1) == cols, name, ": expected shape (*, ", cols, "), got ",
              t.sizes());
  TORCH_CHECK(t.is_contiguous(), name, ": expected a contiguous tensor");
}

// Level table from the Python layout lists; checks they describe the table exactly.
std::vector<Level> make_levels(const std::vector<double>& scales,
                               const std::vector<int64_t>& sizes,
                               const std::vector<int64_t>& strides,
                               const std::vector<int64_t>& offsets,
                               const std::vector<bool>& dense, int64_t rows) {
  const size_t L = scales.size();
  TORCH_CHECK(sizes.size() == L && strides.size() == L && dense.size() == L &&
                  offsets.size() == L + 1,
              "hash grid layout: inconsistent level list lengths");
  TORCH_CHECK(offsets[L] == rows, "hash grid layout: table has ", rows, " rows, levels need ",
              offsets[L]);
  std::vector<Level> out(L);
  for (size_t l = 0; l < L; ++l) {
    const int64_t size = sizes[l];
    TORCH_CHECK(size > 0 && size <= (int64_t(1) << 32) - 1 && offsets[l + 1] - offsets[l] == size,
                "hash grid layout: bad size for level ", l);
    TORCH_CHECK(strides[l] > 0 && (!dense[l] || strides[l] * strides[l] * strides[l] <= size),
                "hash grid layout: bad dense stride for level ", l);
    Level& lv = out[l];
    lv.scale = (float)scales[l];  // the reference holds the scales as float32
    lv.size = (uint32_t)size;
    lv.stride = (uint32_t)strides[l];
    lv.mask = (size & (size - 1)) == 0 ? (uint32_t)(size - 1) : 0u;
    lv.offset = offsets[l];
    lv.dense = dense[l];
  }
  return out;
}

// Returns (out, Jacobian d out / d x as (L, N, F, 3) when need_jac, else undefined). Level-major,
// so each level task writes one contiguous stretch.
std::vector<torch::Tensor> forward(torch::Tensor x, torch::Tensor table,
                                   std::vector<double> scales, std::vector<int64_t> sizes,
                                   std::vector<int64_t> strides, std::vector<int64_t> offsets,
                                   std::vector<bool> dense, bool need_jac) {
  check_tensor(x, "x", 3);
  TORCH_CHECK(table.dim() == 2, "embeddings: expected a 2-D table");
  const int F = (int)table.size(1);
  TORCH_CHECK(F == 1 || F == 2 || F == 4 || F == 8, "embeddings: features per level must be "
              "1, 2, 4 or 8, got ", F);
  check_tensor(table, "embeddings", F);
  const auto levels = make_levels(scales, sizes, strides, offsets, dense, table.size(0));
  const int64_t N = x.size(0), L = (int64_t)levels.size();
  auto out = torch::empty({N, L * F}, x.options());
  torch::Tensor jac;
  if (need_jac) jac = torch::empty({L, N, F, 3}, x.options());
  if (N == 0 || L == 0) return {out, jac};
  const int64_t blocks = (N + kPointsPerTask - 1) / kPointsPerTask;
  const LevelFn fwd = variant().fwd;
  const float* px = x.data_ptr<float>();
  const float* pt = table.data_ptr<float>();
  float* po = out.data_ptr<float>();
  float* pj = need_jac ? jac.data_ptr<float>() : nullptr;
  // Task t = (level t / blocks, block t % blocks): threads sweep one level's table together.
#pragma omp parallel for schedule(dynamic, 1) num_threads(n_threads())
  for (int64_t t = 0; t < L * blocks; ++t) {
    const int64_t l = t / blocks, blk = t % blocks;
    LevelArgs a{};
    a.x = px;
    a.table = pt;
    a.level = levels[l];
    a.begin = blk * kPointsPerTask;
    a.end = std::min(N, a.begin + kPointsPerTask);
    a.out = po;
    a.out_stride = L * F;
    a.col = l * F;
    a.jac = pj ? pj + l * N * F * 3 : nullptr;
    fwd(a, F);
  }
  return {out, jac};
}

// Returns (grad_x or an empty tensor, grad_table or an empty tensor).
std::vector<torch::Tensor> backward(torch::Tensor x, torch::Tensor table, torch::Tensor grad_out,
                                    std::vector<double> scales, std::vector<int64_t> sizes,
                                    std::vector<int64_t> strides, std::vector<int64_t> offsets,
                                    std::vector<bool> dense, bool need_x, bool need_table,
                                    c10::optional<torch::Tensor> jac_opt) {
  check_tensor(x, "x", 3);
  const int F = (int)table.size(1);
  check_tensor(table, "embeddings", F);
  const auto levels = make_levels(scales, sizes, strides, offsets, dense, table.size(0));
  const int64_t N = x.size(0), L = (int64_t)levels.size();
  check_tensor(grad_out, "grad_out", L * F);
  TORCH_CHECK(grad_out.size(0) == N, "grad_out: expected ", N, " rows, got ", grad_out.size(0));
  torch::Tensor gx, gx_levels, gt;
  // With the forward's Jacobian the position gradient is a streaming contraction; without it
  // the level kernels recompute it from the table (one gather per corner).
  const bool use_jac = need_x && jac_opt.has_value() && jac_opt->defined();
  if (use_jac) {
    TORCH_CHECK(jac_opt->is_contiguous() && jac_opt->scalar_type() == torch::kFloat32 &&
                    jac_opt->dim() == 4 && jac_opt->size(0) == L && jac_opt->size(1) == N &&
                    jac_opt->size(2) == F && jac_opt->size(3) == 3,
                "jac: expected a contiguous float32 (L, N, F, 3) tensor");
  }
  if (need_x) {
    gx = torch::empty({N, 3}, x.options());
    if (!use_jac) gx_levels = torch::empty({L, N, 3}, x.options());
  }
  // Dense gradient like the reference's; every row is written by the level that owns it.
  bool zeroed = false;
  if (need_table) {
    gt = grad_buffer(table.size(0), F, &zeroed);
    if (!gt.defined()) gt = torch::empty_like(table);
  }
  const LevelFn bwd = variant().bwd;
  const float* px = x.data_ptr<float>();
  const float* pt = table.data_ptr<float>();
  const float* pg = grad_out.data_ptr<float>();
  float* pgt = need_table ? gt.data_ptr<float>() : nullptr;
  float* pgl = need_x && !use_jac ? gx_levels.data_ptr<float>() : nullptr;
  if (N > 0 && L > 0 && (pgl || need_table)) {
    // One level per task: the level's gradient rows have a single writer (no atomics) and are
    // summed in point order, so the result does not depend on the thread count.
#pragma omp parallel for schedule(dynamic, 1) num_threads(n_threads())
    for (int64_t l = 0; l < L; ++l) {
      const Level& lv = levels[l];
      if (pgt && !zeroed) std::memset(pgt + lv.offset * F, 0, sizeof(float) * lv.size * F);
      LevelArgs a{};
      a.x = px;
      a.table = pt;
      a.level = lv;
      a.begin = 0;
      a.end = N;
      a.out_stride = L * F;
      a.col = l * F;
      a.grad_out = pg;
      a.grad_table = pgt;
      a.grad_x = pgl ? pgl + l * N * 3 : nullptr;
      bwd(a, F);
    }
  } else if (pgt) {
    gt.zero_();
  }
  if (use_jac) {
    // dx_i = sum over levels l and features f of g_i,lF+f * J_l,i,f (in that order:
    // deterministic).
    const float* pjac = jac_opt->data_ptr<float>();
    float* o = gx.data_ptr<float>();
    at::parallel_for(0, N, 2048, [&](int64_t lo, int64_t hi) {
      for (int64_t i = lo; i < hi; ++i) {
        const float* g = pg + i * L * F;
        float d0 = 0.f, d1 = 0.f, d2 = 0.f;
        for (int64_t l = 0; l < L; ++l) {
          const float* jj = pjac + (l * N + i) * F * 3;
          for (int f = 0; f < F; ++f) {
            const float gf = g[l * F + f];
            d0 += gf * jj[3 * f];
            d1 += gf * jj[3 * f + 1];
            d2 += gf * jj[3 * f + 2];
          }
        }
        o[3 * i] = d0;
        o[3 * i + 1] = d1;
        o[3 * i + 2] = d2;
      }
    });
  } else if (need_x) {
    float* o = gx.data_ptr<float>();
    if (L == 0) {
      gx.zero_();
    } else {
      // Sum the per-level position gradients in level order (deterministic).
      at::parallel_for(0, N * 3, 16384, [&](int64_t lo, int64_t hi) {
        for (int64_t k = lo; k < hi; ++k) o[k] = pgl[k];
        for (int64_t l = 1; l < L; ++l) {
          const float* p = pgl + l * N * 3;
          for (int64_t k = lo; k < hi; ++k) o[k] += p[k];
        }
      });
    }
  }
  return {need_x ? gx : torch::Tensor(), need_table ? gt : torch::Tensor()};
}

std::string variant_name() { return variant().name; }

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward", &forward, "Hash-grid encoding (N, 3) -> (N, levels * features)");
  m.def("backward", &backward, "Gradients w.r.t. the inputs and the (dense) table");
  m.def("sh16_forward", &sh16_forward, "Degree-3 SH basis (N, 3) unit dirs -> (N, 16)");
  m.def("sh16_backward", &sh16_backward, "Gradient of sh16_forward w.r.t. the directions");
  m.def("mlp_forward", &mlp_forward,
        "Colour MLPs: (out, h1, h2, h3, s) from the grid and direction codes and the weights");
  m.def("mlp_backward", &mlp_backward,
        "Gradients of the colour MLPs: (code, sh, w0, w1, m, wd, w2) from the saved tensors");
  m.def("set_flush_denormal_all", &set_flush_denormal_all,
        "Flush denormals to zero on the calling and the OpenMP threads; returns the old state");
  m.def("flush_denormal_enabled", &flush_denormal_enabled,
        "Whether the calling thread flushes denormals");
  m.def("release_cached_memory", &release_cached_memory,
        "Unmap the table-gradient block kept for the next backward");
  m.def("variant", &variant_name, "Kernel instruction-set variant chosen for this CPU");
}
