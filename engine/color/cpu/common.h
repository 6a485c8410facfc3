// Data shared by the dispatcher (hashgrid.cpp) and the per-ISA level kernels (kernels.h).
#pragma once
#include <cstdint>

// One resolution level of the grid, exactly as engine/color/hashgrid.py lays it out.
struct Level {
  float scale;      // x in [0, 1] maps to x * scale + 0.5 (float32, as the torch reference)
  uint32_t size;    // table rows of this level
  uint32_t stride;  // dense vertices per axis (resolution + 1)
  uint32_t mask;    // size - 1 when size is a power of two, else 0 (then idx % size)
  int64_t offset;   // first row of this level in the concatenated table
  bool dense;       // vertex index instead of the spatial hash
};

// Arguments of one level pass over the points [begin, end).
struct LevelArgs {
  const float* x;         // (N, 3) inputs in [0, 1]
  const float* table;     // (rows, F) embeddings
  Level level;
  int64_t begin, end;
  // forward
  float* out;             // (N, out_stride): this level writes columns [col, col + F)
  int64_t out_stride;
  int64_t col;
  float* jac;             // (N, F, 3) d out / d x for this level (a slice of (L, N, F, 3)), or null
  // backward
  const float* grad_out;  // (N, out_stride), same columns
  float* grad_table;      // (rows, F) or null; this pass owns the level's rows
  float* grad_x;          // (N, 3) for this level only, or null
};

#define HG_DECLARE(NS)                           \
  namespace NS {                                 \
  void forward_level(const LevelArgs& a, int F);  \
  void backward_level(const LevelArgs& a, int F); \
  }
HG_DECLARE(avx2)
HG_DECLARE(avx512)
#undef HG_DECLARE

