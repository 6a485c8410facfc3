// Per-tile forward and backward blending kernels, written once with GCC vector extensions.
//
// This header is included by one translation unit per instruction set (kernels_avx2.cpp,
// kernels_avx512.cpp); each defines RASTER_NS (the namespace) and RASTER_AVX512 before including
// it, so the same source is compiled for both targets and raster.cpp picks one at run time.
// A tile is 16x16 pixels and one tile row (16 floats) is one vector: two ymm registers on AVX2,
// one zmm register on AVX-512. No OpenMP in here: raster.cpp parallelizes over tiles.
#include <immintrin.h>

#include <cmath>
#include <cstdint>
#include <cstring>

#include "common.h"

namespace RASTER_NS {

typedef float vf __attribute__((vector_size(64)));
typedef int32_t vi __attribute__((vector_size(64)));

static inline vf splat(float x) { return vf{} + x; }
static inline vi splati(int32_t x) { return vi{} + x; }

// Bit i set when lane i of the mask (0 or -1 per lane) is set.
static inline uint32_t movemask(vi m) {
#if RASTER_AVX512
  return (uint32_t)_mm512_movepi32_mask((__m512i)m);
#else
  __m256i lo, hi;
  std::memcpy(&lo, &m, 32);
  std::memcpy(&hi, reinterpret_cast<const char*>(&m) + 32, 32);
  uint32_t a = (uint32_t)_mm256_movemask_ps(_mm256_castsi256_ps(lo));
  uint32_t b = (uint32_t)_mm256_movemask_ps(_mm256_castsi256_ps(hi));
  return a | (b << 8);
#endif
}

static inline float hsum(vf v) {
  float s = 0.f;
  for (int i = 0; i < 16; ++i) s += v[i];
  return s;
}

static inline vf vmin(vf a, vf b) { return a < b ? a : b; }
static inline vf vmax(vf a, vf b) { return a > b ? a : b; }
static inline vf vsel(vi m, vf a, vf b) { return m ? a : b; }

// exp(x) for x <= 0 to ~2 ulp: range reduction by ln 2, degree-7 polynomial, exponent add.
static inline vf vexp(vf x) {
  x = vmax(x, splat(-87.0f));
  const vf t = x * 1.44269504088896341f;
  const vi n = __builtin_convertvector(t - 0.5f, vi);  // round to nearest for t <= 0
  const vf nf = __builtin_convertvector(n, vf);
  vf r = x - nf * 0.693145751953125f;
  r = r - nf * 1.428606765330187045e-06f;
  vf p = splat(1.0f / 5040.0f);
  p = p * r + 1.0f / 720.0f;
  p = p * r + 1.0f / 120.0f;
  p = p * r + 1.0f / 24.0f;
  p = p * r + 1.0f / 6.0f;
  p = p * r + 0.5f;
  p = p * r + 1.0f;
  p = p * r + 1.0f;
  vi bits = (vi)p + (n << 23);
  return (vf)bits;
}

// Pixel rows of the tile (relative, [r0, r1]) a Gaussian can reach; false when none.
static inline bool row_range(const GaussRec& g, int y0, int rows, int& r0, int& r1) {
  const float lo = std::ceil(g.my - g.hy - 0.5f) - (float)y0;
  const float hi = std::floor(g.my + g.hy - 0.5f) - (float)y0;
  if (hi < 0.f || lo > (float)(rows - 1)) return false;
  r0 = lo < 0.f ? 0 : (int)lo;
  r1 = hi > (float)(rows - 1) ? rows - 1 : (int)hi;
  return r0 <= r1;
}

// Whether the Gaussian's cull ellipse crosses row v (pixel centre v + 0.5) inside [x0, x0 + 16).
static inline bool row_hits(const GaussRec& g, float dy, int x0) {
  const float disc = g.two_a_t - g.det * dy * dy;
  if (disc < 0.f) return false;
  const float half = std::sqrt(disc) * g.inv_a;
  const float cx = g.mx + g.b * dy * g.inv_a;  // centre of the row's x interval
  const float ulo = std::ceil(cx - half - 0.5f);
  const float uhi = std::floor(cx + half - 0.5f);
  return uhi >= (float)x0 && ulo <= (float)(x0 + 15);
}

// Forward blending of one tile. acc is scratch of (C + 1) * 256 floats (64-byte aligned).
void forward_tile(const TileFwd& a, int tile_x, int tile_y, float* acc) {
  const int x0 = tile_x * TILE, y0 = tile_y * TILE;
  const int rows = a.height - y0 < TILE ? a.height - y0 : TILE;
  const int cols = a.width - x0 < TILE ? a.width - x0 : TILE;
  const int C = a.channels;
  vf* accv = reinterpret_cast<vf*>(acc);  // [(C + 1)][16 rows]
  for (int i = 0; i < (C + 1) * TILE; ++i) accv[i] = vf{};
  vf T[TILE];
  vi last[TILE];
  vi active[TILE];
  vf lanex;
  vi lane_in;
  for (int l = 0; l < TILE; ++l) {
    lanex[l] = (float)(x0 + l) + 0.5f;
    lane_in[l] = l < cols ? -1 : 0;
  }
  int live_rows = rows;
  for (int r = 0; r < TILE; ++r) {
    T[r] = splat(1.f);
    last[r] = vi{};
    active[r] = r < rows ? lane_in : vi{};
  }
  int64_t evaluated = 0, blended = 0;
  const int32_t begin = a.offsets[tile_y * a.tiles_x + tile_x];
  const int32_t end = a.offsets[tile_y * a.tiles_x + tile_x + 1];
  for (int32_t j = begin; j < end && live_rows > 0; ++j) {
    const int32_t rank = a.list[j];
    const GaussRec& g = a.recs[rank];
    int r0, r1;
    if (!row_range(g, y0, rows, r0, r1)) continue;
    const float* f = a.feats + (int64_t)rank * C;
    const vf dx = g.mx - lanex;
    const vf dx2 = 0.5f * g.a * dx * dx;
    for (int r = r0; r <= r1; ++r) {
      const float dy = g.my - ((float)(y0 + r) + 0.5f);
      if (!row_hits(g, dy, x0)) continue;
      if (!movemask(active[r])) continue;
      evaluated += TILE;
      const vf power = dx2 + (0.5f * g.c * dy * dy) + g.b * dy * dx;
      const vf alpha = vmin(splat(0.999f), g.o * vexp(-power));
      const vi valid = active[r] & (power >= 0.f) & (alpha >= kAlphaMin);
      const vf next_t = T[r] * (1.f - alpha);
      const vi stop = valid & (next_t <= kMinTransmittance);
      const vi blend = valid & ~stop;
      const uint32_t bm = movemask(blend);
      if (bm) {
        blended += __builtin_popcount(bm);
        const vf w = vsel(blend, alpha * T[r], vf{});
        for (int k = 0; k < C; ++k) accv[k * TILE + r] += w * f[k];
        accv[C * TILE + r] += w * g.z;
        T[r] = vsel(blend, next_t, T[r]);
        last[r] = blend ? splati(j - begin + 1) : last[r];
      }
      if (movemask(stop)) {
        active[r] &= ~stop;
        if (!movemask(active[r])) --live_rows;
      }
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

// Backward of one tile: walks the tile's list back to front, undoing the transmittance, and adds
// per-Gaussian gradients (layout GradLayout) into grad (this thread's buffer, indexed by rank).
// scratch holds (3 C + 4) * 256 floats (64-byte aligned).
void backward_tile(const TileBwd& a, int tile_x, int tile_y, float* scratch, float* grad) {
  const int x0 = tile_x * TILE, y0 = tile_y * TILE;
  const int rows = a.height - y0 < TILE ? a.height - y0 : TILE;
  const int cols = a.width - x0 < TILE ? a.width - x0 : TILE;
  const int C = a.channels;
  const int S = C + kGradFixed;
  vf* vimg = reinterpret_cast<vf*>(scratch);  // [(C + 1)][16]: dL/dimage, dL/ddepth last
  vf* after = vimg + (C + 1) * TILE;           // [(C + 1)][16]: sum of w f over later Gaussians
  vf* gacc = after + (C + 1) * TILE;           // [S]: per-Gaussian accumulators
  vf T[TILE], kbg[TILE];
  vi last[TILE];
  int row_last[TILE];
  vf lanex;
  for (int l = 0; l < TILE; ++l) lanex[l] = (float)(x0 + l) + 0.5f;
  int max_last = 0;
  for (int r = 0; r < TILE; ++r) {
    T[r] = vf{};
    kbg[r] = vf{};
    last[r] = vi{};
    row_last[r] = 0;
    for (int k = 0; k <= C; ++k) {
      vimg[k * TILE + r] = vf{};
      after[k * TILE + r] = vf{};
    }
    if (r >= rows) continue;
    const int64_t base = (int64_t)(y0 + r) * a.width + x0;
    for (int l = 0; l < cols; ++l) {
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
    const int32_t rank = a.list[begin + jj];
    const GaussRec& g = a.recs[rank];
    int r0, r1;
    if (!row_range(g, y0, rows, r0, r1)) continue;
    const float* f = a.feats + (int64_t)rank * C;
    const vf dx = g.mx - lanex;
    const vf dx2 = 0.5f * g.a * dx * dx;
    bool touched = false;
    for (int r = r0; r <= r1; ++r) {
      if (jj >= row_last[r]) continue;
      const float dy = g.my - ((float)(y0 + r) + 0.5f);
      if (!row_hits(g, dy, x0)) continue;
      const vf power = dx2 + (0.5f * g.c * dy * dy) + g.b * dy * dx;
      const vf e = vexp(-power);
      const vf oe = g.o * e;
      const vf alpha = vmin(splat(0.999f), oe);
      const vi valid = (splati(jj) < last[r]) & (power >= 0.f) & (alpha >= kAlphaMin);
      if (!movemask(valid)) continue;
      if (!touched) {
        for (int s = 0; s < S; ++s) gacc[s] = vf{};
        touched = true;
      }
      const vf ra = 1.f / (1.f - alpha);
      const vf t_before = vsel(valid, T[r] * ra, T[r]);
      T[r] = t_before;
      const vf w = vsel(valid, alpha * t_before, vf{});
      // dL/dalpha = sum_k (f_k T - after_k / (1 - alpha)) dL/dout_k + T_final/(1-alpha) * K.
      vf v_alpha = kbg[r] * ra;
      for (int k = 0; k < C; ++k) {
        const vf gk = vimg[k * TILE + r];
        v_alpha += (f[k] * t_before - after[k * TILE + r] * ra) * gk;
        gacc[kGradFixed + k] += w * gk;
        after[k * TILE + r] += w * f[k];
      }
      {
        const vf gd = vimg[C * TILE + r];
        v_alpha += (g.z * t_before - after[C * TILE + r] * ra) * gd;
        gacc[kGradZ] += w * gd;
        after[C * TILE + r] += w * g.z;
      }
      // The 0.999 clamp has no gradient (gsplat: only when o * exp(-power) <= 0.999).
      const vi live = valid & (oe <= 0.999f);
      const vf va = vsel(live, v_alpha, vf{});
      const vf v_sigma = -oe * va;
      gacc[kGradO] += e * va;
      gacc[kGradA] += 0.5f * dx * dx * v_sigma;
      gacc[kGradB] += dx * dy * v_sigma;
      gacc[kGradC] += (0.5f * dy * dy) * v_sigma;
      gacc[kGradX] += v_sigma * (g.a * dx + g.b * dy);
      gacc[kGradY] += v_sigma * (g.b * dx + g.c * dy);
    }
    if (touched) {
      float* out = grad + (int64_t)rank * S;
      for (int s = 0; s < S; ++s) out[s] += hsum(gacc[s]);
    }
  }
}

}  // namespace RASTER_NS
