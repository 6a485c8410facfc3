// Native CPU rasterizer: depth sort, tile binning, and the OpenMP loops over tiles that call the
// per-ISA tile kernels (kernels.h). Projection stays in PyTorch (engine/raster/projection.py); this
// file receives the projected 2D Gaussians and returns the blended image plus the per-Gaussian
// 2D gradients for the backward pass.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "common.h"

namespace {

using FwdFn = void (*)(const TileFwd&, int, int, float*);
using BwdFn = void (*)(const TileBwd&, int, int, float*, float*);
using RcpFn = void (*)(const float*, const float*, float*, int64_t);

struct Variant {
  const char* name;
  FwdFn fwd;
  BwdFn bwd;
  RcpFn rcp;
};

#if defined(__x86_64__)
bool cpu_has_avx512() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
         __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl");
}

const Variant kAvx2 = {"avx2", avx2::forward_tile, avx2::backward_tile, avx2::reciprocal};
const Variant kAvx512 = {"avx512", avx512::forward_tile, avx512::backward_tile,
                         avx512::reciprocal};
#endif
// Generic vectors only (vec_portable.h): the kernels of every other CPU (NEON on aarch64), and
// on x86 a variant the tests select to check the same code natively.
const Variant kPortable = {"portable", portable::forward_tile, portable::backward_tile,
                           portable::reciprocal};

// The variants this CPU can run, the default first: AVX-512 where the CPU has it, then the
// AVX2 baseline, then the portable kernels (x86 builds); the portable kernels alone elsewhere.
std::vector<const Variant*> runnable_variants() {
#if defined(__x86_64__)
  if (cpu_has_avx512()) return {&kAvx512, &kAvx2, &kPortable};
  return {&kAvx2, &kPortable};
#else
  return {&kPortable};
#endif
}

const Variant* find_variant(const std::string& name) {
  for (const Variant* v : runnable_variants())
    if (name == v->name) return v;
  return nullptr;
}

// The kernel variant for this CPU; SPARSESPLAT_RASTER_ISA names one to force instead (avx2 for
// the baseline on an AVX-512 CPU, portable; an unknown or unsupported name is ignored).
const Variant* pick_variant() {
  const char* force = std::getenv("SPARSESPLAT_RASTER_ISA");
  const Variant* forced = force ? find_variant(force) : nullptr;
  return forced ? forced : runnable_variants().front();
}

// The variant in use. Read once at the start of each forward/backward call, so switching it
// (set_variant, for tests that run both ISAs in one process) never mixes kernels in one call.
std::atomic<const Variant*>& current_variant() {
  static std::atomic<const Variant*> v{pick_variant()};
  return v;
}

const Variant& variant() { return *current_variant().load(); }

std::vector<std::string> available_variants() {
  std::vector<std::string> names;
  for (const Variant* v : runnable_variants()) names.push_back(v->name);
  return names;
}

// Selects the variant by name; returns the previous one's. Unknown or unsupported: error.
std::string set_variant(const std::string& name) {
  const Variant* want = find_variant(name);
  if (want == nullptr) {
#if defined(__x86_64__)
    TORCH_CHECK(name != kAvx512.name, "this CPU has no AVX-512 (avx512f/bw/dq/vl)");
#endif
    std::string names;
    for (const std::string& n : available_variants()) names += (names.empty() ? "" : ", ") + n;
    TORCH_CHECK(false, "unknown rasterizer kernel variant '", name, "' (this CPU runs: ", names,
                ")");
  }
  return current_variant().exchange(want)->name;
}

struct AlignedBuf {
  float* p = nullptr;
  explicit AlignedBuf(size_t n) {
    size_t bytes = ((n * sizeof(float) + 63) / 64) * 64;
    p = static_cast<float*>(std::aligned_alloc(64, bytes > 0 ? bytes : 64));
    if (!p) throw std::bad_alloc();
  }
  ~AlignedBuf() { std::free(p); }
};

// Stable LSD radix sort of ids by positive float keys (their bit patterns order like the floats).
void radix_sort(std::vector<uint32_t>& keys, std::vector<int32_t>& ids) {
  const size_t n = keys.size();
  std::vector<uint32_t> k2(n);
  std::vector<int32_t> i2(n);
  for (int shift = 0; shift < 32; shift += 8) {
    size_t count[257] = {0};
    for (size_t i = 0; i < n; ++i) count[((keys[i] >> shift) & 255) + 1]++;
    for (int b = 0; b < 256; ++b) count[b + 1] += count[b];
    for (size_t i = 0; i < n; ++i) {
      const size_t d = count[(keys[i] >> shift) & 255]++;
      k2[d] = keys[i];
      i2[d] = ids[i];
    }
    keys.swap(k2);
    ids.swap(i2);
  }
}

int n_threads() { return std::max(1, at::get_num_threads()); }

void check_cpu_f32(const torch::Tensor& t, const char* name) {
  TORCH_CHECK(t.device().is_cpu(), name, " must be a CPU tensor");
  TORCH_CHECK(t.scalar_type() == torch::kFloat32, name, " must be float32");
  TORCH_CHECK(t.is_contiguous(), name, " must be contiguous");
}

}  // namespace

std::string variant_name() { return variant().name; }

// Returns {image (C,H,W), depth (1,H,W), alpha (1,H,W), stats int64 [evaluated, blended]} and,
// when keep_state, the state the backward needs: {recs, feats_sorted, rank_to_id, offsets, list,
// t_final, last}.
std::vector<torch::Tensor> forward(torch::Tensor means2d, torch::Tensor conics,
                                   torch::Tensor opacities, torch::Tensor depths,
                                   torch::Tensor radii, torch::Tensor features, torch::Tensor bg,
                                   int64_t width, int64_t height, bool keep_state) {
  check_cpu_f32(means2d, "means2d");
  check_cpu_f32(conics, "conics");
  check_cpu_f32(opacities, "opacities");
  check_cpu_f32(depths, "depths");
  check_cpu_f32(features, "features");
  check_cpu_f32(bg, "background");
  TORCH_CHECK(radii.scalar_type() == torch::kInt32 && radii.is_contiguous(), "radii must be int32");
  const int64_t N = means2d.size(0);
  const int C = (int)features.size(1);
  const int W = (int)width, H = (int)height;
  const int tiles_x = (W + TILE - 1) / TILE, tiles_y = (H + TILE - 1) / TILE;
  const int n_tiles = tiles_x * tiles_y;
  const float* m2 = means2d.data_ptr<float>();
  const float* con = conics.data_ptr<float>();
  const float* op = opacities.data_ptr<float>();
  const float* dep = depths.data_ptr<float>();
  const int32_t* rad = radii.data_ptr<int32_t>();
  const float* feat = features.data_ptr<float>();

  // 1. Visible Gaussians in depth order (ties by index, like gsplat's stable radix sort).
  std::vector<uint32_t> keys;
  std::vector<int32_t> ids;
  keys.reserve(N);
  ids.reserve(N);
  for (int64_t i = 0; i < N; ++i) {
    if (rad[2 * i] <= 0 || rad[2 * i + 1] <= 0) continue;
    uint32_t k;
    std::memcpy(&k, &dep[i], 4);
    keys.push_back(k);
    ids.push_back((int32_t)i);
  }
  radix_sort(keys, ids);
  const int64_t M = (int64_t)ids.size();

  // 2. Packed records and depth-ordered features.
  auto recs_t = torch::empty({M * (int64_t)(sizeof(GaussRec) / sizeof(float))}, torch::kFloat32);
  auto feats_t = torch::empty({M, C}, torch::kFloat32);
  auto rank_t = torch::from_blob(ids.data(), {M}, torch::kInt32).clone();
  GaussRec* recs = reinterpret_cast<GaussRec*>(recs_t.data_ptr<float>());
  float* fs = feats_t.data_ptr<float>();
  std::vector<int32_t> tx0(M), tx1(M), ty0(M), ty1(M);
  at::parallel_for(0, M, 2048, [&](int64_t lo, int64_t hi) {
    for (int64_t r = lo; r < hi; ++r) {
      const int64_t i = ids[r];
      GaussRec g;
      std::memset(&g, 0, sizeof(g));
      g.mx = m2[2 * i];
      g.my = m2[2 * i + 1];
      g.a = con[3 * i];
      g.b = con[3 * i + 1];
      g.c = con[3 * i + 2];
      g.o = op[i];
      g.z = dep[i];
      // Cull level: alpha >= 1/255 needs power <= ln(255 o); a small margin keeps every pair
      // that passes the alpha test inside the cull ellipse despite rounding.
      const float t = std::log(std::max(g.o * 255.0f, 1.0f));
      const float tm = t * 1.002f + 1e-3f;
      g.det = (float)((double)g.a * g.c - (double)g.b * g.b);  // double: cancels when thin
      g.inv_a = 1.0f / g.a;
      g.two_a_t = 2.0f * g.a * tm;
      g.hx = std::sqrt(std::max(2.0f * tm * g.c / g.det, 0.0f));
      g.hy = std::sqrt(std::max(2.0f * tm * g.a / g.det, 0.0f));
      recs[r] = g;
      for (int k = 0; k < C; ++k) fs[r * C + k] = feat[i * C + k];
      // Tile range of pixels whose centres fall in the ellipse's bounding box.
      const double ulo = std::ceil((double)g.mx - g.hx - 0.5), uhi = std::floor((double)g.mx + g.hx - 0.5);
      const double vlo = std::ceil((double)g.my - g.hy - 0.5), vhi = std::floor((double)g.my + g.hy - 0.5);
      if (!(uhi >= 0 && ulo <= W - 1 && vhi >= 0 && vlo <= H - 1)) {
        tx0[r] = 1;
        tx1[r] = 0;
        ty0[r] = 1;
        ty1[r] = 0;
        continue;
      }
      tx0[r] = (int32_t)(std::max(ulo, 0.0) / TILE);
      tx1[r] = (int32_t)(std::min(uhi, (double)(W - 1)) / TILE);
      ty0[r] = (int32_t)(std::max(vlo, 0.0) / TILE);
      ty1[r] = (int32_t)(std::min(vhi, (double)(H - 1)) / TILE);
    }
  });

  // 3. Tile lists in depth order: count, prefix sum, fill (rank order keeps each list sorted).
  auto offsets_t = torch::zeros({n_tiles + 1}, torch::kInt32);
  int32_t* offsets = offsets_t.data_ptr<int32_t>();
  for (int64_t r = 0; r < M; ++r)
    for (int ty = ty0[r]; ty <= ty1[r]; ++ty)
      for (int tx = tx0[r]; tx <= tx1[r]; ++tx) offsets[ty * tiles_x + tx + 1]++;
  for (int t = 0; t < n_tiles; ++t) offsets[t + 1] += offsets[t];
  auto list_t = torch::empty({(int64_t)offsets[n_tiles]}, torch::kInt32);
  int32_t* list = list_t.data_ptr<int32_t>();
  {
    std::vector<int32_t> cursor(offsets, offsets + n_tiles);
    for (int64_t r = 0; r < M; ++r)
      for (int ty = ty0[r]; ty <= ty1[r]; ++ty)
        for (int tx = tx0[r]; tx <= tx1[r]; ++tx) list[cursor[ty * tiles_x + tx]++] = (int32_t)r;
  }

  // 4. Blend tiles in parallel.
  auto image = torch::empty({C, H, W}, torch::kFloat32);
  auto depth = torch::empty({1, H, W}, torch::kFloat32);
  auto alpha = torch::empty({1, H, W}, torch::kFloat32);
  torch::Tensor t_final, last;
  if (keep_state) {
    t_final = torch::empty({H, W}, torch::kFloat32);
    last = torch::empty({H, W}, torch::kInt32);
  }
  std::vector<int64_t> evaluated(n_tiles, 0), blended(n_tiles, 0);
  TileFwd args{recs, fs, list, offsets, tiles_x, W, H, C, bg.data_ptr<float>(),
               image.data_ptr<float>(), depth.data_ptr<float>(), alpha.data_ptr<float>(),
               keep_state ? t_final.data_ptr<float>() : nullptr,
               keep_state ? last.data_ptr<int32_t>() : nullptr, evaluated.data(), blended.data()};
  const FwdFn fwd = variant().fwd;
#pragma omp parallel num_threads(n_threads())
  {
    AlignedBuf scratch((size_t)(C + 1) * TILE * TILE);
#pragma omp for schedule(dynamic, 1)
    for (int t = 0; t < n_tiles; ++t) fwd(args, t % tiles_x, t / tiles_x, scratch.p);
  }
  auto stats = torch::zeros({2}, torch::kInt64);
  for (int t = 0; t < n_tiles; ++t) {
    stats.data_ptr<int64_t>()[0] += evaluated[t];
    stats.data_ptr<int64_t>()[1] += blended[t];
  }
  std::vector<torch::Tensor> out = {image, depth, alpha, stats};
  if (keep_state) {
    for (auto& t : {recs_t, feats_t, rank_t, offsets_t, list_t, t_final, last}) out.push_back(t);
  }
  return out;
}

// Returns {v_means2d (N,2), v_conics (N,3), v_opacities (N,), v_depths (N,), v_features (N,C)};
// with geometry = false, v_means2d and v_conics are zeros (not computed). v_depth_opacity, when
// defined, is the gradient of a depth loss that may move only the opacities: it adds to
// v_opacities alone.
std::vector<torch::Tensor> backward(torch::Tensor recs_t, torch::Tensor feats_t,
                                    torch::Tensor rank_t, torch::Tensor offsets_t,
                                    torch::Tensor list_t, torch::Tensor t_final,
                                    torch::Tensor last, torch::Tensor bg, torch::Tensor v_image,
                                    torch::Tensor v_depth, torch::Tensor v_alpha,
                                    c10::optional<torch::Tensor> v_depth_opacity, int64_t n,
                                    bool geometry) {
  check_cpu_f32(v_image, "grad image");
  check_cpu_f32(v_depth, "grad depth");
  check_cpu_f32(v_alpha, "grad alpha");
  const float* v_dop = nullptr;
  if (v_depth_opacity.has_value() && v_depth_opacity->defined()) {
    check_cpu_f32(*v_depth_opacity, "grad opacity-only depth");
    v_dop = v_depth_opacity->data_ptr<float>();
  }
  const int C = (int)feats_t.size(1);
  const int64_t M = feats_t.size(0);
  const int H = (int)t_final.size(0), W = (int)t_final.size(1);
  const int tiles_x = (W + TILE - 1) / TILE, tiles_y = (H + TILE - 1) / TILE;
  const int n_tiles = tiles_x * tiles_y;
  const int S = C + kGradFixed;
  const int nt = n_threads();
  std::vector<float> grads((size_t)nt * M * S, 0.0f);
  TileBwd args{reinterpret_cast<const GaussRec*>(recs_t.data_ptr<float>()),
               feats_t.data_ptr<float>(), list_t.data_ptr<int32_t>(),
               offsets_t.data_ptr<int32_t>(), tiles_x, W, H, C, bg.data_ptr<float>(),
               t_final.data_ptr<float>(), last.data_ptr<int32_t>(), v_image.data_ptr<float>(),
               v_depth.data_ptr<float>(), v_alpha.data_ptr<float>(), v_dop, geometry};
  const BwdFn bwd = variant().bwd;
#pragma omp parallel num_threads(nt)
  {
    AlignedBuf scratch((size_t)((C + 1) * TILE + S + TILE) * TILE);
    float* mine = grads.data() + (size_t)omp_get_thread_num() * M * S;
    // A fixed tile -> thread map (round robin): each thread's partial sums, and so the rounding
    // of their total, are the same on every run with the same thread count. With a dynamic
    // schedule they depended on which thread grabbed which tile, and a seeded multi-threaded
    // run did not reproduce itself. Neighbouring tiles cost about the same, so the round robin
    // keeps the threads about equally loaded.
#pragma omp for schedule(static, 1)
    for (int t = 0; t < n_tiles; ++t) bwd(args, t % tiles_x, t / tiles_x, scratch.p, mine);
  }
  auto v_m2 = torch::zeros({n, 2}, torch::kFloat32);
  auto v_con = torch::zeros({n, 3}, torch::kFloat32);
  auto v_op = torch::zeros({n}, torch::kFloat32);
  auto v_dep = torch::zeros({n}, torch::kFloat32);
  auto v_feat = torch::zeros({n, C}, torch::kFloat32);
  const int32_t* rank = rank_t.data_ptr<int32_t>();
  float *pm = v_m2.data_ptr<float>(), *pc = v_con.data_ptr<float>();
  float *po = v_op.data_ptr<float>(), *pd = v_dep.data_ptr<float>(), *pf = v_feat.data_ptr<float>();
  at::parallel_for(0, M, 4096, [&](int64_t lo, int64_t hi) {
    std::vector<float> g(S);
    for (int64_t r = lo; r < hi; ++r) {
      for (int s = 0; s < S; ++s) {
        float acc = 0.f;
        for (int t = 0; t < nt; ++t) acc += grads[((size_t)t * M + r) * S + s];
        g[s] = acc;
      }
      const int64_t i = rank[r];
      pm[2 * i] = g[kGradX];
      pm[2 * i + 1] = g[kGradY];
      pc[3 * i] = g[kGradA];
      pc[3 * i + 1] = g[kGradB];
      pc[3 * i + 2] = g[kGradC];
      po[i] = g[kGradO];
      pd[i] = g[kGradZ];
      for (int k = 0; k < C; ++k) pf[i * C + k] = g[kGradFixed + k];
    }
  });
  return {v_m2, v_con, v_op, v_dep, v_feat};
}

// The kernels' reciprocal of x from the estimate r (see vrcp_refine in kernels.h), exposed so a
// test can feed it estimates at the hardware's error bound: the result must not depend on which
// vendor's estimate the CPU returns.
torch::Tensor reciprocal(const torch::Tensor& x, const torch::Tensor& estimate) {
  check_cpu_f32(x, "x");
  check_cpu_f32(estimate, "estimate");
  TORCH_CHECK(x.dim() == 1 && estimate.sizes() == x.sizes(), "x and estimate: equal 1-D shapes");
  auto xc = x.contiguous(), rc = estimate.contiguous();
  auto out = torch::empty_like(xc);
  variant().rcp(xc.data_ptr<float>(), rc.data_ptr<float>(), out.data_ptr<float>(), xc.numel());
  return out;
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward", &forward, "Blend projected Gaussians (forward)");
  m.def("backward", &backward, "Gradients w.r.t. the projected Gaussians");
  m.def("variant", &variant_name, "Kernel instruction-set variant in use");
  m.def("available_variants", &available_variants, "Kernel variants this CPU can run");
  m.def("set_variant", &set_variant, "Use the named kernel variant; returns the previous one");
  m.def("reciprocal", &reciprocal, "The kernels' 1/x from the estimate r (tests)");
}
