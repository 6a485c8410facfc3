// Fused EWA projection of 3D Gaussians (forward + analytic backward) for the CPU rasterizer.
//
// The float32 kernel restates engine/raster/projection.py::project() operation for operation, so
// its outputs agree with the torch function to float32 rounding and its backward is the gradient
// of the same graph: the torch.where masks (culled rows use the stand-in z = 1 and get no conic or
// depth gradient), the clamp of the Jacobian's x/z and y/z (zero gradient outside the limits) and
// the clamp of the quaternion's norm. The torch version runs ~100 small ops each way; here one
// pass over the Gaussians does each direction, 8 Gaussians per AVX2 vector (GCC vector
// extensions; branches become lane selects; the few x86 intrinsics have builtin twins for other
// CPUs, where GCC lowers each vector to the target's, e.g. two NEON registers on aarch64). The backward recomputes the per-Gaussian forward
// quantities from the inputs instead of saving them: a few hundred flops per Gaussian are cheaper
// than writing and reading back ~60 floats per Gaussian.
//
// Built with -ffp-contract=off so each a * b + c rounds twice, as the separate torch ops do.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

namespace {

constexpr double kAlphaThreshold = 1.0 / 255.0;  // projection.ALPHA_THRESHOLD
constexpr double kMaxExtentSigma = 3.33;         // projection.MAX_EXTENT_SIGMA
constexpr double kBigRadius = 1073741824.0;      // 2**30, the int32-safe cap of project()
constexpr int64_t kGrain = 1024;                 // Gaussians per parallel chunk
constexpr int L = 8;                             // lanes per vector

typedef float V __attribute__((vector_size(32)));
typedef int32_t VI __attribute__((vector_size(32)));

inline V splat(float x) { return V{x, x, x, x, x, x, x, x}; }
// std::max / std::min semantics (the first argument wins unless the comparison holds), so a NaN
// behaves as in the scalar code and in torch.clamp.
inline V vmax(V a, V b) { return a < b ? b : a; }
inline V vmin(V a, V b) { return b < a ? b : a; }
#if defined(__x86_64__)
inline V vsqrt(V x) { return (V)_mm256_sqrt_ps((__m256)x); }
inline V vfloor(V x) {
  return (V)_mm256_round_ps((__m256)x, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
}
inline V vfma(V a, V b, V c) { return (V)_mm256_fmadd_ps((__m256)a, (__m256)b, (__m256)c); }
#else
// Lane loops of the builtins (GCC vectorizes them); fmaf is fused even without a vector FMA.
inline V vsqrt(V x) {
  V r;
  for (int l = 0; l < L; ++l) r[l] = __builtin_sqrtf(x[l]);
  return r;
}
inline V vfloor(V x) {
  V r;
  for (int l = 0; l < L; ++l) r[l] = __builtin_floorf(x[l]);
  return r;
}
inline V vfma(V a, V b, V c) {
  V r;
  for (int l = 0; l < L; ++l) r[l] = __builtin_fmaf(a[l], b[l], c[l]);
  return r;
}
#endif
inline VI visfinite(V x) { return (x - x) == splat(0.0f); }  // inf - inf and NaN are NaN
inline V vselect(VI m, V a, V b) { return m ? a : b; }

// exp(x) over the whole float range (overflow to inf, gradual underflow to 0, NaN kept), ~1 ulp:
// Cody-Waite reduction by ln 2, the Cephes degree-6 polynomial, and 2^n applied in two halves so
// results in the subnormal range stay right (sigmoid(-100) must be 0, as in torch, not 4e-39).
inline V vexp(V x) {
  const V xc = vmin(vmax(x, splat(-104.0f)), splat(89.0f));
  const V fx = vfloor(xc * 1.44269504088896341f + 0.5f);
  V r = xc - fx * 0.693359375f;
  r = r + fx * 2.12194440e-4f;
  const V r2 = r * r;
  V p = splat(1.9875691500e-4f);
  p = vfma(p, r, splat(1.3981999507e-3f));
  p = vfma(p, r, splat(8.3334519073e-3f));
  p = vfma(p, r, splat(4.1665795894e-2f));
  p = vfma(p, r, splat(1.6666665459e-1f));
  p = vfma(p, r, splat(5.0000001201e-1f));
  p = vfma(p, r2, r + 1.0f);
  const VI n = __builtin_convertvector(fx, VI);  // in [-150, 129]
  const VI n1 = n >> 1, n2 = n - n1;              // each half in [-75, 65]: a normal power of 2
  V y = p * (V)((n1 + 127) << 23);
  y = y * (V)((n2 + 127) << 23);
  y = x > splat(88.72283935546875f) ? splat(INFINITY) : y;
  y = x < splat(-103.97208404541015625f) ? splat(0.0f) : y;
  return x != x ? x : y;
}

typedef double VD __attribute__((vector_size(32)));
typedef int64_t VL __attribute__((vector_size(32)));

inline VD splatd(double x) { return VD{x, x, x, x}; }
inline VD vmaxd(VD a, VD b) { return a < b ? b : a; }
inline VD vmind(VD a, VD b) { return b < a ? b : a; }

// Natural log of positive normal doubles to < 1 ulp (fdlibm's __ieee754_log: x = 2^k m with
// m in [sqrt(2)/2, sqrt(2)), log m = f - f^2/2 + s (f^2/2 + R(s^2)), s = f / (2 + f)). Used for
// the float64 screen extent, where a last-bit difference from torch's log could only matter if
// ext * sqrt(a) landed within 1e-16 of an integer before the ceil.
inline VD vlogd(VD x) {
  const VL bits = (VL)x;
  const VL e = (bits >> 52) & 0x7ff;
  // m in [1, 2) from the mantissa; fold m > sqrt(2) to m / 2 (one more power of two).
  VD m = (VD)((bits & 0x000fffffffffffffLL) | 0x3ff0000000000000LL);
  // k = e - 1023 exactly: OR e into the mantissa of 2^52 and subtract 2^52 + 1023.
  VD k = (VD)(e | 0x4330000000000000LL) - (4503599627370496.0 + 1023.0);
  const auto big = m > splatd(1.4142135623730951);
  m = big ? m * 0.5 : m;
  k = big ? k + 1.0 : k;
  const VD f = m - 1.0;
  const VD s = f / (2.0 + f);
  const VD z = s * s;
  const VD w = z * z;
  const VD t1 = w * (3.999999999940941908e-01 +
                     w * (2.222219843214978396e-01 + w * 1.531383769920937332e-01));
  const VD t2 = z * (6.666666666666735130e-01 +
                     w * (2.857142874366239149e-01 +
                          w * (1.818357216161805012e-01 + w * 1.479819860511658591e-01)));
  const VD r = t2 + t1;
  const VD hfsq = 0.5 * f * f;
  return k * 6.93147180369123816490e-01 -
         ((hfsq - (s * (hfsq + r) + k * 1.90821492927058770002e-10)) - f);
}

// The low / high four lanes of a float vector (or mask), widened to double (or int64) lanes.
inline VD lo_half(V v) {
  return __builtin_convertvector(__builtin_shufflevector(v, v, 0, 1, 2, 3), VD);
}
inline VD hi_half(V v) {
  return __builtin_convertvector(__builtin_shufflevector(v, v, 4, 5, 6, 7), VD);
}
inline VL lo_half(VI m) {
  return __builtin_convertvector(__builtin_shufflevector(m, m, 0, 1, 2, 3), VL);
}
inline VL hi_half(VI m) {
  return __builtin_convertvector(__builtin_shufflevector(m, m, 4, 5, 6, 7), VL);
}
#if defined(__x86_64__)
inline VD vsqrtd(VD x) { return (VD)_mm256_sqrt_pd((__m256d)x); }
inline VD vceild(VD x) {
  return (VD)_mm256_round_pd((__m256d)x, _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC);
}
#else
inline VD vsqrtd(VD x) {
  VD r;
  for (int l = 0; l < 4; ++l) r[l] = __builtin_sqrt(x[l]);
  return r;
}
inline VD vceild(VD x) {
  VD r;
  for (int l = 0; l < 4; ++l) r[l] = __builtin_ceil(x[l]);
  return r;
}
#endif

// Camera and projection constants, rounded to float32 where torch rounds a Python scalar to the
// float32 tensor's dtype.
struct Cam {
  double centre[3];  // camera centre in world space, float64 (project() forms m - c in float64)
  float rot[9];      // world-to-camera rotation, row-major, rounded to float32
  float fx, fy, cx, cy;
  float near, far, eps;
  float lim_xn, lim_xp, lim_yn, lim_yp;  // FoV clamp of x/z to [-lim_xn, lim_xp], y/z likewise
  double width, height;
};

Cam make_cam(const std::vector<double>& p, int64_t width, int64_t height) {
  TORCH_CHECK(p.size() == 19, "camera parameters: expected 19 values, got ", p.size());
  Cam c{};
  for (int k = 0; k < 3; ++k) c.centre[k] = p[k];
  for (int k = 0; k < 9; ++k) c.rot[k] = (float)p[3 + k];
  const double fx = p[12], fy = p[13], cx = p[14], cy = p[15];
  const double w = (double)width, h = (double)height;
  c.fx = (float)fx;
  c.fy = (float)fy;
  c.cx = (float)cx;
  c.cy = (float)cy;
  c.near = (float)p[16];
  c.far = (float)p[17];
  c.eps = (float)p[18];
  // Same expressions as project(), in float64, then rounded as torch.clamp rounds its bounds.
  c.lim_xp = (float)((w - cx) / fx + 0.3 * (0.5 * w / fx));
  c.lim_xn = (float)(cx / fx + 0.3 * (0.5 * w / fx));
  c.lim_yp = (float)((h - cy) / fy + 0.3 * (0.5 * h / fy));
  c.lim_yn = (float)(cy / fy + 0.3 * (0.5 * h / fy));
  c.width = w;
  c.height = h;
  return c;
}

// project()'s opacity-aware screen extent for four Gaussians, in float64 as there:
// ext = min(sqrt(2 ln(max(o, 1/255) * 255)), 3.33), r = ceil(ext sqrt(max(a, 0))), kept (else 0)
// where valid, o >= 1/255, the box overlaps the image and both radii are positive; capped at 2^30.
inline void radii4(const Cam& cam, VD op, VD a, VD c, VD mx, VD my, VL valid, int32_t* out) {
  const VD zero = splatd(0.0), thr = splatd(kAlphaThreshold);
  const VD lg = vlogd(vmaxd(op, thr) / thr);
  const VD ext = vmind(vsqrtd(2.0 * lg), splatd(kMaxExtentSigma));
  const VD rx = vceild(ext * vsqrtd(vmaxd(a, zero)));
  const VD ry = vceild(ext * vsqrtd(vmaxd(c, zero)));
  const VL inside = (mx + rx > zero) & (mx - rx < splatd(cam.width)) & (my + ry > zero) &
                    (my - ry < splatd(cam.height));
  const VL keep = valid & (op >= thr) & inside & (rx > zero) & (ry > zero);
  const VD big = splatd(kBigRadius);
  const VD rxk = keep ? vmind(rx, big) : zero;
  const VD ryk = keep ? vmind(ry, big) : zero;
  for (int l = 0; l < 4; ++l) {
    out[2 * l] = (int32_t)rxk[l];
    out[2 * l + 1] = (int32_t)ryk[l];
  }
}

// Up to 8 Gaussians' inputs, transposed to one vector per component.
struct In {
  V rel[3];  // m - c, formed in float64 and rounded to float32
  V ls[3];   // log scales
  V q[4];    // quaternion wxyz, as given
};

// Loads Gaussians [i, i + n), n <= 8; missing lanes get harmless values and are never stored.
inline void load(const Cam& cam, const float* pm, const float* ps, const float* pq, int64_t i,
                 int n, In& in) {
  alignas(32) float buf[10][L] = {};
  for (int l = 0; l < n; ++l) {
    const int64_t j = i + l;
    for (int k = 0; k < 3; ++k) {
      buf[k][l] = (float)((double)pm[3 * j + k] - cam.centre[k]);
      buf[3 + k][l] = ps[3 * j + k];
    }
    for (int k = 0; k < 4; ++k) buf[6 + k][l] = pq[4 * j + k];
  }
  for (int k = 0; k < 3; ++k) {
    std::memcpy(&in.rel[k], buf[k], sizeof(V));
    std::memcpy(&in.ls[k], buf[3 + k], sizeof(V));
  }
  for (int k = 0; k < 4; ++k) std::memcpy(&in.q[k], buf[6 + k], sizeof(V));
}

inline V load1(const float* p, int64_t i, int n) {
  alignas(32) float buf[L] = {};
  std::memcpy(buf, p + i, sizeof(float) * n);
  V v;
  std::memcpy(&v, buf, sizeof(V));
  return v;
}

// Everything the forward computes per Gaussian that the backward needs again.
struct Geo {
  V x, y, z;          // view-space centre
  VI in_depth;        // near < z < far
  V inv_z;            // 1 / z, or 1 outside the depth range (the stand-in z = 1)
  V qn[4];            // normalized quaternion (w, x, y, z)
  V nrm;              // |q| before the clamp
  V m[9];             // R_view R_q
  V s[3];             // exp(log_scales)
  V v[9];             // V = R_view R_q S
  V ux, uy;           // clamped x/z, y/z
  VI ux_free, uy_free;  // the clamp passed its input (torch.clamp's gradient flows)
  V gx, gy;           // fx / z, fy / z
  V p0[3], p1[3];     // V row 0 - ux V row 2, V row 1 - uy V row 2
  V t0[3], t1[3];     // rows of J V
  V a, b, c;          // 2D covariance + eps on the diagonal
  V cr[3];            // t0 x t1
  V det;              // |t0 x t1|^2 + eps (a + c - eps)
  VI valid;           // in_depth, det > 0 and finite
};

// The float32 forward of project() up to the conics, in the same order of operations.
inline void geometry(const Cam& cam, const In& in, Geo& g) {
  const float* R = cam.rot;
  const V* rel = in.rel;
  g.x = R[0] * rel[0] + R[1] * rel[1] + R[2] * rel[2];
  g.y = R[3] * rel[0] + R[4] * rel[1] + R[5] * rel[2];
  g.z = R[6] * rel[0] + R[7] * rel[1] + R[8] * rel[2];
  g.in_depth = (g.z > cam.near) & (g.z < cam.far);
  const V one = splat(1.0f);
  g.inv_z = one / vselect(g.in_depth, g.z, one);

  const V qw = in.q[0], qx = in.q[1], qy = in.q[2], qz = in.q[3];
  g.nrm = vsqrt(qw * qw + qx * qx + qy * qy + qz * qz);
  const V nc = vmax(g.nrm, splat(1e-12f));
  const V w = qw / nc, x = qx / nc, y = qy / nc, z = qz / nc;
  g.qn[0] = w;
  g.qn[1] = x;
  g.qn[2] = y;
  g.qn[3] = z;
  V rq[9];
  rq[0] = 1.0f - 2.0f * (y * y + z * z);
  rq[1] = 2.0f * (x * y - w * z);
  rq[2] = 2.0f * (x * z + w * y);
  rq[3] = 2.0f * (x * y + w * z);
  rq[4] = 1.0f - 2.0f * (x * x + z * z);
  rq[5] = 2.0f * (y * z - w * x);
  rq[6] = 2.0f * (x * z - w * y);
  rq[7] = 2.0f * (y * z + w * x);
  rq[8] = 1.0f - 2.0f * (x * x + y * y);
  for (int k = 0; k < 3; ++k) g.s[k] = vexp(in.ls[k]);
  for (int r = 0; r < 3; ++r)
    for (int j = 0; j < 3; ++j) {
      g.m[3 * r + j] = R[3 * r] * rq[j] + R[3 * r + 1] * rq[3 + j] + R[3 * r + 2] * rq[6 + j];
      g.v[3 * r + j] = g.m[3 * r + j] * g.s[j];
    }

  const V xz = g.x * g.inv_z, yz = g.y * g.inv_z;
  const V lxn = splat(-cam.lim_xn), lxp = splat(cam.lim_xp);
  const V lyn = splat(-cam.lim_yn), lyp = splat(cam.lim_yp);
  g.ux = vmin(vmax(xz, lxn), lxp);
  g.uy = vmin(vmax(yz, lyn), lyp);
  g.ux_free = (xz >= lxn) & (xz <= lxp);
  g.uy_free = (yz >= lyn) & (yz <= lyp);
  g.gx = cam.fx * g.inv_z;
  g.gy = cam.fy * g.inv_z;
  for (int k = 0; k < 3; ++k) {
    g.p0[k] = g.v[k] - g.ux * g.v[6 + k];
    g.p1[k] = g.v[3 + k] - g.uy * g.v[6 + k];
    g.t0[k] = g.gx * g.p0[k];
    g.t1[k] = g.gy * g.p1[k];
  }
  const V* t0 = g.t0;
  const V* t1 = g.t1;
  g.a = (t0[0] * t0[0] + t0[1] * t0[1] + t0[2] * t0[2]) + cam.eps;
  g.b = t0[0] * t1[0] + t0[1] * t1[1] + t0[2] * t1[2];
  g.c = (t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]) + cam.eps;
  g.cr[0] = t0[1] * t1[2] - t0[2] * t1[1];
  g.cr[1] = t0[2] * t1[0] - t0[0] * t1[2];
  g.cr[2] = t0[0] * t1[1] - t0[1] * t1[0];
  const V cc = g.cr[0] * g.cr[0] + g.cr[1] * g.cr[1] + g.cr[2] * g.cr[2];
  g.det = cc + cam.eps * (g.a + g.c - cam.eps);
  g.valid = g.in_depth & (g.det > splat(0.0f)) & visfinite(g.det);
}

void check_f32(const torch::Tensor& t, const char* name, int64_t n, int64_t cols) {
  TORCH_CHECK(t.device().is_cpu(), name, " must be a CPU tensor");
  TORCH_CHECK(t.scalar_type() == torch::kFloat32, name, " must be float32");
  TORCH_CHECK(t.is_contiguous(), name, " must be contiguous");
  if (cols > 0) {
    TORCH_CHECK(t.dim() == 2 && t.size(0) == n && t.size(1) == cols, name, ": expected shape (",
                n, ", ", cols, ")");
  } else {
    TORCH_CHECK(t.dim() == 1 && t.size(0) == n, name, ": expected shape (", n, ")");
  }
}

// Stores lanes [0, n) of the K vectors to the rows i.. of a contiguous (N, K) output.
template <int K>
inline void store(float* out, int64_t i, int n, const V (&vs)[K]) {
  for (int l = 0; l < n; ++l)
    for (int k = 0; k < K; ++k) out[K * (i + l) + k] = vs[k][l];
}

}  // namespace

#if defined(__x86_64__)
std::string variant_name() { return "avx2-f32"; }
#else
std::string variant_name() { return "portable-f32"; }
#endif

// Returns {means2d (N,2), conics (N,3), depths (N), opacities (N), radii (N,2) int32}.
// cam = [centre (3, float64), rotation (9, row-major), fx, fy, cx, cy, near, far, eps2d].
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor log_scales,
                                           torch::Tensor quats, torch::Tensor logits,
                                           std::vector<double> cam_params, int64_t width,
                                           int64_t height) {
  const int64_t N = means.size(0);
  check_f32(means, "means", N, 3);
  check_f32(log_scales, "log_scales", N, 3);
  check_f32(quats, "quats", N, 4);
  check_f32(logits, "opacity_logits", N, 0);
  const Cam cam = make_cam(cam_params, width, height);
  auto f32 = torch::TensorOptions().dtype(torch::kFloat32);
  torch::Tensor means2d = torch::empty({N, 2}, f32);
  torch::Tensor conics = torch::empty({N, 3}, f32);
  torch::Tensor depths = torch::empty({N}, f32);
  torch::Tensor opac = torch::empty({N}, f32);
  torch::Tensor radii = torch::empty({N, 2}, f32.dtype(torch::kInt32));
  const float* pm = means.data_ptr<float>();
  const float* ps = log_scales.data_ptr<float>();
  const float* pq = quats.data_ptr<float>();
  const float* pl = logits.data_ptr<float>();
  float* om = means2d.data_ptr<float>();
  float* oc = conics.data_ptr<float>();
  float* od = depths.data_ptr<float>();
  float* oo = opac.data_ptr<float>();
  int32_t* orad = radii.data_ptr<int32_t>();
  at::parallel_for(0, N, kGrain, [&](int64_t lo, int64_t hi) {
    In in;
    Geo g;
    for (int64_t i = lo; i < hi; i += L) {
      const int n = (int)std::min<int64_t>(L, hi - i);
      load(cam, pm, ps, pq, i, n, in);
      geometry(cam, in, g);
      const V zero = splat(0.0f);
      const V m2[2] = {(cam.fx * g.x) * g.inv_z + cam.cx, (cam.fy * g.y) * g.inv_z + cam.cy};
      const V con[3] = {vselect(g.valid, g.c / g.det, zero), vselect(g.valid, -g.b / g.det, zero),
                        vselect(g.valid, g.a / g.det, zero)};
      const V dep[1] = {vselect(g.in_depth, g.z, zero)};
      const V o[1] = {1.0f / (1.0f + vexp(-load1(pl, i, n)))};
      store(om, i, n, m2);
      store(oc, i, n, con);
      store(od, i, n, dep);
      store(oo, i, n, o);

      // Opacity-aware screen extent (float64), four lanes at a time.
      alignas(32) int32_t rad[2 * L];
      radii4(cam, lo_half(o[0]), lo_half(g.a), lo_half(g.c), lo_half(m2[0]), lo_half(m2[1]),
             lo_half(g.valid), rad);
      radii4(cam, hi_half(o[0]), hi_half(g.a), hi_half(g.c), hi_half(m2[0]), hi_half(m2[1]),
             hi_half(g.valid), rad + L);
      std::memcpy(orad + 2 * i, rad, sizeof(int32_t) * 2 * n);
    }
  });
  return {means2d, conics, depths, opac, radii};
}

// Gradients of project()'s differentiable outputs w.r.t. {means, log_scales, quats, logits}.
// Upstream gradients must be contiguous float32 of the output shapes. need[k] false leaves the
// k-th gradient undefined (None in Python) and skips the work only it needs.
std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor log_scales,
                                            torch::Tensor quats, torch::Tensor opacities,
                                            std::vector<double> cam_params, int64_t width,
                                            int64_t height, torch::Tensor v_means2d,
                                            torch::Tensor v_conics, torch::Tensor v_depths,
                                            torch::Tensor v_opacities, std::vector<bool> need) {
  const int64_t N = means.size(0);
  check_f32(means, "means", N, 3);
  check_f32(log_scales, "log_scales", N, 3);
  check_f32(quats, "quats", N, 4);
  check_f32(opacities, "opacities", N, 0);
  check_f32(v_means2d, "v_means2d", N, 2);
  check_f32(v_conics, "v_conics", N, 3);
  check_f32(v_depths, "v_depths", N, 0);
  check_f32(v_opacities, "v_opacities", N, 0);
  TORCH_CHECK(need.size() == 4, "need: expected 4 flags");
  const bool need_m = need[0], need_s = need[1], need_q = need[2], need_o = need[3];
  const Cam cam = make_cam(cam_params, width, height);
  auto f32 = torch::TensorOptions().dtype(torch::kFloat32);
  torch::Tensor g_means = need_m ? torch::empty({N, 3}, f32) : torch::Tensor();
  torch::Tensor g_scales = need_s ? torch::empty({N, 3}, f32) : torch::Tensor();
  torch::Tensor g_quats = need_q ? torch::empty({N, 4}, f32) : torch::Tensor();
  torch::Tensor g_logits = need_o ? torch::empty({N}, f32) : torch::Tensor();
  const float* pm = means.data_ptr<float>();
  const float* ps = log_scales.data_ptr<float>();
  const float* pq = quats.data_ptr<float>();
  const float* po = opacities.data_ptr<float>();
  const float* vm2 = v_means2d.data_ptr<float>();
  const float* vcon = v_conics.data_ptr<float>();
  const float* vdep = v_depths.data_ptr<float>();
  const float* vop = v_opacities.data_ptr<float>();
  float* gm = need_m ? g_means.data_ptr<float>() : nullptr;
  float* gs = need_s ? g_scales.data_ptr<float>() : nullptr;
  float* gq = need_q ? g_quats.data_ptr<float>() : nullptr;
  float* gl = need_o ? g_logits.data_ptr<float>() : nullptr;
  const bool geo = need_m || need_s || need_q;
  const float* R = cam.rot;

  if (need_o) {
    // torch's sigmoid backward: grad * (1 - y) * y. Elementwise, so a plain loop vectorizes.
    at::parallel_for(0, N, 4 * kGrain, [&](int64_t lo, int64_t hi) {
      for (int64_t i = lo; i < hi; ++i) gl[i] = (vop[i] * (1.0f - po[i])) * po[i];
    });
  }
  if (!geo) return {g_means, g_scales, g_quats, g_logits};

  at::parallel_for(0, N, kGrain, [&](int64_t lo, int64_t hi) {
    In in;
    Geo g;
    alignas(32) float buf[6][L];
    for (int64_t i = lo; i < hi; i += L) {
      const int n = (int)std::min<int64_t>(L, hi - i);
      load(cam, pm, ps, pq, i, n, in);
      geometry(cam, in, g);
      std::memset(buf, 0, sizeof(buf));
      for (int l = 0; l < n; ++l) {
        const int64_t j = i + l;
        buf[0][l] = vm2[2 * j];
        buf[1][l] = vm2[2 * j + 1];
        buf[2][l] = vcon[3 * j];
        buf[3][l] = vcon[3 * j + 1];
        buf[4][l] = vcon[3 * j + 2];
        buf[5][l] = vdep[j];
      }
      V gmx, gmy, gA, gB, gC, gd;  // upstream gradients of means2d, conics, depths
      std::memcpy(&gmx, buf[0], sizeof(V));
      std::memcpy(&gmy, buf[1], sizeof(V));
      std::memcpy(&gA, buf[2], sizeof(V));
      std::memcpy(&gB, buf[3], sizeof(V));
      std::memcpy(&gC, buf[4], sizeof(V));
      std::memcpy(&gd, buf[5], sizeof(V));
      const V zero = splat(0.0f);

      // means2d = (fx x) inv_z + cx, (fy y) inv_z + cy (unmasked: culled rows use inv_z = 1).
      V v_x = cam.fx * (gmx * g.inv_z);
      V v_y = cam.fy * (gmy * g.inv_z);
      V v_inv_z = gmx * (cam.fx * g.x) + gmy * (cam.fy * g.y);
      V v_z = vselect(g.in_depth, gd, zero);  // depths = where(in_depth, z, 0)

      // conics = where(valid, (c, -b, a) / det, 0): the chain below runs on every lane and its
      // results are selected on `valid` at the end, so an invalid lane contributes exact zeros
      // even where its geometry overflowed (torch's backward would form 0 * inf = NaN there).
      const V det = vselect(g.valid, g.det, splat(1.0f));
      const V inv_det = 1.0f / det;
      V v_a = gC * inv_det, v_b = -gB * inv_det, v_c = gA * inv_det;
      const V v_det = -(gA * (g.c * inv_det) - gB * (g.b * inv_det) + gC * (g.a * inv_det)) *
                      inv_det;
      // det = |t0 x t1|^2 + eps (a + c - eps).
      v_a = v_a + cam.eps * v_det;
      v_c = v_c + cam.eps * v_det;
      V v_cr[3];
      for (int k = 0; k < 3; ++k) v_cr[k] = 2.0f * g.cr[k] * v_det;
      const V* t0 = g.t0;
      const V* t1 = g.t1;
      // d(t0 x t1) . u: w.r.t. t0 it is t1 x u, w.r.t. t1 it is u x t0.
      V v_t0[3] = {t1[1] * v_cr[2] - t1[2] * v_cr[1], t1[2] * v_cr[0] - t1[0] * v_cr[2],
                   t1[0] * v_cr[1] - t1[1] * v_cr[0]};
      V v_t1[3] = {v_cr[1] * t0[2] - v_cr[2] * t0[1], v_cr[2] * t0[0] - v_cr[0] * t0[2],
                   v_cr[0] * t0[1] - v_cr[1] * t0[0]};
      for (int k = 0; k < 3; ++k) {
        v_t0[k] = v_t0[k] + 2.0f * v_a * t0[k] + v_b * t1[k];
        v_t1[k] = v_t1[k] + 2.0f * v_c * t1[k] + v_b * t0[k];
      }
      // t0 = gx (V0 - ux V2), t1 = gy (V1 - uy V2).
      V v_gx = zero, v_gy = zero, v_ux = zero, v_uy = zero;
      V v_v[9];
      for (int k = 0; k < 3; ++k) {
        v_gx = v_gx + v_t0[k] * g.p0[k];
        v_gy = v_gy + v_t1[k] * g.p1[k];
        const V vp0 = g.gx * v_t0[k], vp1 = g.gy * v_t1[k];
        v_v[k] = vp0;
        v_v[3 + k] = vp1;
        v_v[6 + k] = -(g.ux * vp0 + g.uy * vp1);
        v_ux = v_ux - vp0 * g.v[6 + k];
        v_uy = v_uy - vp1 * g.v[6 + k];
      }
      for (int k = 0; k < 9; ++k) v_v[k] = vselect(g.valid, v_v[k], zero);
      v_ux = vselect(g.valid & g.ux_free, v_ux, zero);
      v_uy = vselect(g.valid & g.uy_free, v_uy, zero);
      v_x = v_x + v_ux * g.inv_z;
      v_y = v_y + v_uy * g.inv_z;
      const V v_inv_z_con = cam.fx * v_gx + cam.fy * v_gy + v_ux * g.x + v_uy * g.y;
      v_inv_z = v_inv_z + vselect(g.valid, v_inv_z_con, zero);
      // inv_z = 1 / where(in_depth, z, 1).
      v_z = v_z + vselect(g.in_depth, -v_inv_z * (g.inv_z * g.inv_z), zero);

      if (need_m) {
        // mc = R rel with rel = m - c (the float64 round trip passes the gradient unchanged).
        V out[3];
        for (int k = 0; k < 3; ++k) out[k] = R[k] * v_x + R[3 + k] * v_y + R[6 + k] * v_z;
        store(gm, i, n, out);
      }
      if (need_s) {
        // V = M diag(s), s = exp(log_scales): v_ls_j = (sum_r v_V[r][j] M[r][j]) s_j.
        V out[3];
        for (int j = 0; j < 3; ++j)
          out[j] = vselect(g.valid,
                           (v_v[j] * g.m[j] + v_v[3 + j] * g.m[3 + j] + v_v[6 + j] * g.m[6 + j]) *
                               g.s[j],
                           zero);  // only the conics depend on the scales (and overflow: 0 * inf)
        store(gs, i, n, out);
      }
      if (need_q) {
        // v_M = v_V diag(s); v_Rq = R_view^T v_M.
        V G[9];
        for (int k = 0; k < 3; ++k)
          for (int j = 0; j < 3; ++j)
            G[3 * k + j] = R[k] * (v_v[j] * g.s[j]) + R[3 + k] * (v_v[3 + j] * g.s[j]) +
                           R[6 + k] * (v_v[6 + j] * g.s[j]);
        const V w = g.qn[0], x = g.qn[1], y = g.qn[2], z = g.qn[3];
        const V vw = 2.0f * (-z * G[1] + y * G[2] + z * G[3] - x * G[5] - y * G[6] + x * G[7]);
        const V vx = 2.0f * (y * G[1] + z * G[2] + y * G[3] - 2.0f * x * G[4] - w * G[5] +
                             z * G[6] + w * G[7] - 2.0f * x * G[8]);
        const V vy = 2.0f * (-2.0f * y * G[0] + x * G[1] + w * G[2] + x * G[3] + z * G[5] -
                             w * G[6] + z * G[7] - 2.0f * y * G[8]);
        const V vz = 2.0f * (-2.0f * z * G[0] - w * G[1] + x * G[2] + w * G[3] - 2.0f * z * G[4] +
                             y * G[5] + x * G[6] + y * G[7]);
        // q = Q / max(|Q|, 1e-12): where |Q| >= 1e-12 the norm's gradient removes the radial
        // part, below it the clamp stops it and only the division's gradient remains.
        const V nc = vmax(g.nrm, splat(1e-12f));
        const V dot = vselect(g.nrm >= splat(1e-12f), vw * w + vx * x + vy * y + vz * z, zero);
        const V out[4] = {vselect(g.valid, (vw - dot * w) / nc, zero),
                          vselect(g.valid, (vx - dot * x) / nc, zero),
                          vselect(g.valid, (vy - dot * y) / nc, zero),
                          vselect(g.valid, (vz - dot * z) / nc, zero)};
        store(gq, i, n, out);
      }
    }
  });
  return {g_means, g_scales, g_quats, g_logits};
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward", &project_forward, "EWA projection of 3D Gaussians (forward)");
  m.def("backward", &project_backward, "Gradients of the EWA projection");
  m.def("variant", &variant_name, "Kernel variant (for the loader's log line)");
}
