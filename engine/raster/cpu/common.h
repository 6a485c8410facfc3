// Data shared by the dispatcher (raster.cpp) and the per-ISA tile kernels (kernels.h).
#pragma once
#include <cstdint>

constexpr int TILE = 16;                       // tile side in pixels; one tile row = 16 floats
constexpr float kAlphaMin = 1.0f / 255.0f;     // gsplat ALPHA_THRESHOLD
constexpr float kMinTransmittance = 1e-4f;     // stop before T would reach this

// Gradient slots per Gaussian in the backward buffers, then one slot per feature channel.
constexpr int kGradX = 0, kGradY = 1, kGradA = 2, kGradB = 3, kGradC = 4, kGradO = 5, kGradZ = 6;
constexpr int kGradFixed = 7;

// One visible Gaussian in depth order, packed into a cache line.
struct alignas(64) GaussRec {
  float mx, my;      // projected centre (pixels)
  float a, b, c;     // conic: power = 0.5 (a dx^2 + c dy^2) + b dx dy
  float o;           // opacity
  float z;           // view-space depth
  float hy;          // half height of the cull ellipse (pixels)
  float hx;          // half width of the cull ellipse (pixels)
  float two_a_t;     // 2 a t, with t the cull level ln(255 o) plus a margin
  float det;         // a c - b^2
  float inv_a;       // 1 / a
  float pad[4];
};

struct TileFwd {
  const GaussRec* recs;
  const float* feats;       // (M, C) in depth order
  const int32_t* list;      // tile lists of ranks, concatenated
  const int32_t* offsets;   // (tiles + 1)
  int tiles_x, width, height, channels;
  const float* bg;          // (C,)
  float* image;             // (C, H, W)
  float* depth;             // (H, W)
  float* alpha;             // (H, W)
  float* t_final;           // (H, W) or null when no backward will follow
  int32_t* last;            // (H, W) or null: 1 + position in the tile list of the last blend
  int64_t* evaluated;       // (tiles,)
  int64_t* blended;         // (tiles,)
};

struct TileBwd {
  const GaussRec* recs;
  const float* feats;
  const int32_t* list;
  const int32_t* offsets;
  int tiles_x, width, height, channels;
  const float* bg;
  const float* t_final;
  const int32_t* last;
  const float* v_image;     // (C, H, W)
  const float* v_depth;     // (H, W)
  const float* v_alpha;     // (H, W)
  // (H, W) or null: the gradient of a loss on the rendered depth that may move only the
  // opacities (the soft-depth term fused into the photometric render). It adds to the opacity
  // gradient alone: no 2D mean, conic or z gradient comes from it.
  const float* v_depth_opacity;
  bool geometry;            // false: only opacity, depth and feature gradients are wanted
};

// The tile kernels of each variant (kernels.h, one translation unit each); the x86 ones exist
// only in x86 builds, the portable one everywhere.
#define RASTER_DECLARE(NS)                                                                  \
  namespace NS {                                                                           \
  void forward_tile(const TileFwd& a, int tile_x, int tile_y, float* acc);                 \
  void backward_tile(const TileBwd& a, int tile_x, int tile_y, float* scratch, float* grad); \
  void reciprocal(const float* x, const float* estimate, float* out, int64_t n);           \
  }
#if defined(__x86_64__)
RASTER_DECLARE(avx2)
RASTER_DECLARE(avx512)
#endif
RASTER_DECLARE(portable)
#undef RASTER_DECLARE
