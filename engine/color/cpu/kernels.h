// Per-level hash-grid kernels (forward, backward), written once and compiled per instruction set.
//
// Included by kernels_avx2.cpp and kernels_avx512.cpp, each defining HG_NS (the namespace) first;
// hashgrid.cpp picks one at run time. No OpenMP in here: hashgrid.cpp parallelizes over
// (level, block of points) in the forward and over levels in the backward, so one call of a
// kernel touches one level's table only (a few MB: cache friendly, and in the backward the level's
// gradient rows belong to a single thread, so there are no atomics and the sums are
// deterministic).
//
// Each block of points is done in two phases: a branch-free arithmetic phase (positions, the 8
// corner indices and trilinear weights, which the compiler vectorizes) and a gather phase whose
// loads are independent, so the out-of-order core overlaps the cache misses of the hashed levels.
// The arithmetic is float32 in the reference's order (x * scale, then + 0.5) and the build
// disables FMA contraction, so both implementations pick the same cell for every input, cell
// boundaries included; sums over corners and levels may round differently (tests: ~1e-6).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "common.h"

namespace HG_NS {

constexpr int kBlock = 64;
constexpr uint32_t kPrime1 = 2654435761u;
constexpr uint32_t kPrime2 = 805459861u;

// Phase 1 for one block: per point the inside flag, per corner the row (relative to the level's
// first row) and the weight, plus the per-axis fractions for the position gradient.
struct Block {
  alignas(64) uint32_t idx[8][kBlock];
  alignas(64) float w[8][kBlock];
  alignas(64) float frac[3][kBlock];
  alignas(64) int32_t inside[kBlock];
};

// The weight and row of corner C (bit k: the upper vertex along axis k) for the block's points,
// from the per-axis fractions t and lower vertices g. C is a template argument so each loop is
// straight-line arithmetic that the compiler vectorizes across points.
template <int C>
static inline void corner(const float (&t)[3][kBlock], const uint32_t (&g)[3][kBlock],
                          bool dense, uint32_t s1, uint32_t s2, int n, Block& b) {
  constexpr uint32_t c0 = C & 1, c1 = (C >> 1) & 1, c2 = (C >> 2) & 1;
  for (int i = 0; i < n; ++i) {
    const float a0 = c0 ? t[0][i] : 1.f - t[0][i];
    const float a1 = c1 ? t[1][i] : 1.f - t[1][i];
    const float a2 = c2 ? t[2][i] : 1.f - t[2][i];
    b.w[C][i] = (a0 * a1) * a2;
  }
  if (dense) {
    for (int i = 0; i < n; ++i)
      b.idx[C][i] = (g[0][i] + c0) + (g[1][i] + c1) * s1 + (g[2][i] + c2) * s2;
  } else {
    for (int i = 0; i < n; ++i)
      b.idx[C][i] = (g[0][i] + c0) ^ ((g[1][i] + c1) * kPrime1) ^ ((g[2][i] + c2) * kPrime2);
  }
}

// One axis: the position inside the cell and the cell's lower vertex, x * scale + 0.5 in float32.
// x is in [0, 1] here (outside points were moved to 0), so p >= 0.5 and below 2^31: truncation
// is floor, exactly. (GCC does not vectorize std::floor without -fno-trapping-math; the
// conversion pair does.)
static inline void cell(const float* __restrict x, float scale, int n, float* __restrict frac,
                        uint32_t* __restrict g) {
  for (int i = 0; i < n; ++i) {
    const float p = x[i] * scale + 0.5f;
    const int32_t v = (int32_t)p;
    frac[i] = p - (float)v;
    g[i] = (uint32_t)v;
  }
}

// Written as separate loops over the block's points, each free of per-point control flow and
// small indexed arrays, so that every one vectorizes (one loop with all of it did not, and ran
// scalar). The arithmetic and its order are the reference's, so the results are the same bits.
static inline void corners(const float* __restrict x, const Level& lv, int64_t begin, int n,
                           Block& b) {
  const float scale = lv.scale;
  const uint32_t s1 = lv.stride, s2 = lv.stride * lv.stride;
  alignas(64) float xs[3][kBlock];
  for (int i = 0; i < n; ++i) {  // (N, 3) rows to one array per axis
    const float* p = x + 3 * (begin + i);
    xs[0][i] = p[0];
    xs[1][i] = p[1];
    xs[2][i] = p[2];
  }
  alignas(64) uint32_t g[3][kBlock];
  for (int i = 0; i < n; ++i) {
    const float x0 = xs[0][i], x1 = xs[1][i], x2 = xs[2][i];
    // NaN fails every comparison, so it counts as outside (as in the reference).
    const bool in = (x0 >= 0.f) & (x0 <= 1.f) & (x1 >= 0.f) & (x1 <= 1.f) & (x2 >= 0.f) &
                    (x2 <= 1.f);
    b.inside[i] = in ? -1 : 0;
    // Outside points are evaluated at the origin (valid indices) and masked later.
    xs[0][i] = in ? x0 : 0.f;
    xs[1][i] = in ? x1 : 0.f;
    xs[2][i] = in ? x2 : 0.f;
  }
  cell(xs[0], scale, n, b.frac[0], g[0]);
  cell(xs[1], scale, n, b.frac[1], g[1]);
  cell(xs[2], scale, n, b.frac[2], g[2]);
  const bool dense = lv.dense;
  corner<0>(b.frac, g, dense, s1, s2, n, b);
  corner<1>(b.frac, g, dense, s1, s2, n, b);
  corner<2>(b.frac, g, dense, s1, s2, n, b);
  corner<3>(b.frac, g, dense, s1, s2, n, b);
  corner<4>(b.frac, g, dense, s1, s2, n, b);
  corner<5>(b.frac, g, dense, s1, s2, n, b);
  corner<6>(b.frac, g, dense, s1, s2, n, b);
  corner<7>(b.frac, g, dense, s1, s2, n, b);
  // Fold into the level: dense indices are already < size (make_levels checks stride^3 <= size
  // and the largest corner index is stride^3 - 1), hashed ones take a mask for power-of-two
  // sizes (every hashed level of the grid's layout) and a true modulo otherwise.
  if (dense) return;
  if (lv.mask) {
    for (int c = 0; c < 8; ++c)
      for (int i = 0; i < n; ++i) b.idx[c][i] &= lv.mask;
  } else {
    for (int c = 0; c < 8; ++c)
      for (int i = 0; i < n; ++i) b.idx[c][i] %= lv.size;
  }
}

template <int F>
static inline void gather(const float* __restrict tab, const Block& b, int n,
                          float (&rows)[8][F][kBlock]) {
  for (int c = 0; c < 8; ++c) {
    for (int i = 0; i < n; ++i) {
      const float* r = tab + (int64_t)b.idx[c][i] * F;
      for (int f = 0; f < F; ++f) rows[c][f][i] = r[f];
    }
  }
}

// gather() for the points flagged live; the others get zero rows (their gradient is zero).
template <int F>
static inline void gather_live(const float* __restrict tab, const Block& b, int n,
                               const bool* live, float (&rows)[8][F][kBlock]) {
  for (int c = 0; c < 8; ++c) {
    for (int i = 0; i < n; ++i) {
      const float* r = tab + (int64_t)b.idx[c][i] * F;
      for (int f = 0; f < F; ++f) rows[c][f][i] = live[i] ? r[f] : 0.f;
    }
  }
}

template <int F>
static inline void prefetch(const float* tab, const float* tab2, const Block& b, int64_t start,
                            int n, const LevelArgs& a) {
  for (int i = 0; i < n; ++i) {
    if (!b.inside[i]) continue;
    if (a.grad_out) {  // backward: rows of points with a zero upstream gradient are not touched
      const float* go = a.grad_out + (start + i) * a.out_stride + a.col;
      bool any = false;
      for (int f = 0; f < F; ++f) any |= go[f] != 0.f;
      if (!any) continue;
    }
    for (int c = 0; c < 8; ++c) {
      const int64_t off = (int64_t)b.idx[c][i] * F;
      if (tab) __builtin_prefetch(tab + off, 0, 3);
      if (tab2) __builtin_prefetch(tab2 + off, 1, 3);
    }
  }
}

// Runs body(block, start, n) over [begin, end) in blocks, one block of corners ahead: the next
// block's corners are computed and their rows prefetched (from tab and tab2, either may be null)
// before the current block is processed, so its cache misses overlap this block's work.
template <int F, typename Body>
static inline void for_blocks(const LevelArgs& a, const float* tab, const float* tab2,
                              Body body) {
  Block bufs[2];
  int cur = 0;
  int64_t start = a.begin;
  if (start >= a.end) return;
  int n = (int)std::min<int64_t>(kBlock, a.end - start);
  corners(a.x, a.level, start, n, bufs[cur]);
  while (true) {
    const int64_t next = start + n;
    int n_next = 0;
    if (next < a.end) {
      n_next = (int)std::min<int64_t>(kBlock, a.end - next);
      corners(a.x, a.level, next, n_next, bufs[cur ^ 1]);
      prefetch<F>(tab, tab2, bufs[cur ^ 1], next, n_next, a);
    }
    body(bufs[cur], start, n);
    if (next >= a.end) break;
    start = next;
    n = n_next;
    cur ^= 1;
  }
}

template <int F>
static void forward_impl(const LevelArgs& a) {
  const float* __restrict tab = a.table + a.level.offset * F;
  const float scale = a.level.scale;
  alignas(64) float rows[8][F][kBlock];
  alignas(64) float acc[F][kBlock];
  alignas(64) float jd[3][kBlock];
  for_blocks<F>(a, tab, nullptr, [&](const Block& b, int64_t start, int n) {
    gather<F>(tab, b, n, rows);
    for (int f = 0; f < F; ++f) {
      for (int i = 0; i < n; ++i) acc[f][i] = 0.f;
      for (int c = 0; c < 8; ++c)
        for (int i = 0; i < n; ++i) acc[f][i] += b.w[c][i] * rows[c][f][i];
      for (int i = 0; i < n; ++i) acc[f][i] = b.inside[i] ? acc[f][i] : 0.f;
    }
    for (int i = 0; i < n; ++i) {
      float* o = a.out + (start + i) * a.out_stride + a.col;
      for (int f = 0; f < F; ++f) o[f] = acc[f][i];
    }
    if (!a.jac) return;
    // d out_f / d x_k = scale * sum_c row_c,f * (+-1) * (weights of the two other axes), from
    // the rows gathered above: the backward then needs no gather for the position gradient.
    for (int f = 0; f < F; ++f) {
      for (int k = 0; k < 3; ++k)
        for (int i = 0; i < n; ++i) jd[k][i] = 0.f;
      for (int c = 0; c < 8; ++c) {
        const int c0 = c & 1, c1 = (c >> 1) & 1, c2 = (c >> 2) & 1;
        for (int i = 0; i < n; ++i) {
          const float t0 = b.frac[0][i], t1 = b.frac[1][i], t2 = b.frac[2][i];
          const float w0 = c0 ? t0 : 1.f - t0, w1 = c1 ? t1 : 1.f - t1, w2 = c2 ? t2 : 1.f - t2;
          const float r = rows[c][f][i];
          jd[0][i] += (c0 ? r : -r) * (w1 * w2);
          jd[1][i] += (c1 ? r : -r) * (w0 * w2);
          jd[2][i] += (c2 ? r : -r) * (w0 * w1);
        }
      }
      for (int i = 0; i < n; ++i) {
        float* j = a.jac + ((start + i) * F + f) * 3;
        const bool in = b.inside[i];
        j[0] = in ? jd[0][i] * scale : 0.f;
        j[1] = in ? jd[1][i] * scale : 0.f;
        j[2] = in ? jd[2][i] * scale : 0.f;
      }
    }
  });
}

template <int F>
static void backward_impl(const LevelArgs& a) {
  const float* __restrict tab = a.table + a.level.offset * F;
  float* __restrict gtab = a.grad_table ? a.grad_table + a.level.offset * F : nullptr;
  const float scale = a.level.scale;
  alignas(64) float rows[8][F][kBlock];
  alignas(64) float g[F][kBlock];
  alignas(64) float d[3][kBlock];
  alignas(64) float s[kBlock];
  bool live[kBlock];
  // Prefetch the table rows only when they are read (position gradient), and the gradient rows.
  for_blocks<F>(a, a.grad_x ? tab : nullptr, gtab, [&](const Block& b, int64_t start, int n) {
    // Outside points get zero features: zero upstream gradient, hence no contribution at all.
    // Points whose upstream gradient is exactly zero (Gaussians the view did not render) add
    // exact zeros, so they are skipped too: no scatter, no gather.
    for (int i = 0; i < n; ++i) {
      const float* go = a.grad_out + (start + i) * a.out_stride + a.col;
      bool any = false;
      for (int f = 0; f < F; ++f) {
        g[f][i] = b.inside[i] ? go[f] : 0.f;
        any |= g[f][i] != 0.f;
      }
      live[i] = any;
    }
    if (gtab) {
      for (int c = 0; c < 8; ++c) {
        for (int i = 0; i < n; ++i) {
          if (!live[i]) continue;
          float* r = gtab + (int64_t)b.idx[c][i] * F;
          const float w = b.w[c][i];
          for (int f = 0; f < F; ++f) r[f] += w * g[f][i];
        }
      }
    }
    if (a.grad_x) {
      // d out / d frac_k = sum_c <g, row_c> * (+-1) * (weights of the two other axes).
      gather_live<F>(tab, b, n, live, rows);
      for (int k = 0; k < 3; ++k)
        for (int i = 0; i < n; ++i) d[k][i] = 0.f;
      for (int c = 0; c < 8; ++c) {
        const int c0 = c & 1, c1 = (c >> 1) & 1, c2 = (c >> 2) & 1;
        for (int i = 0; i < n; ++i) s[i] = 0.f;
        for (int f = 0; f < F; ++f)
          for (int i = 0; i < n; ++i) s[i] += g[f][i] * rows[c][f][i];
        for (int i = 0; i < n; ++i) {
          const float t0 = b.frac[0][i], t1 = b.frac[1][i], t2 = b.frac[2][i];
          const float w0 = c0 ? t0 : 1.f - t0, w1 = c1 ? t1 : 1.f - t1, w2 = c2 ? t2 : 1.f - t2;
          const float si = s[i];
          d[0][i] += (c0 ? si : -si) * (w1 * w2);
          d[1][i] += (c1 ? si : -si) * (w0 * w2);
          d[2][i] += (c2 ? si : -si) * (w0 * w1);
        }
      }
      for (int i = 0; i < n; ++i) {
        float* gx = a.grad_x + 3 * (start + i);
        gx[0] = d[0][i] * scale;
        gx[1] = d[1][i] * scale;
        gx[2] = d[2][i] * scale;
      }
    }
  });
}

void forward_level(const LevelArgs& a, int F) {
  switch (F) {
    case 1: return forward_impl<1>(a);
    case 2: return forward_impl<2>(a);
    case 4: return forward_impl<4>(a);
    case 8: return forward_impl<8>(a);
  }
}

void backward_level(const LevelArgs& a, int F) {
  switch (F) {
    case 1: return backward_impl<1>(a);
    case 2: return backward_impl<2>(a);
    case 4: return backward_impl<4>(a);
    case 8: return backward_impl<8>(a);
  }
}

}  // namespace HG_NS
