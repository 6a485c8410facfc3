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
#if defined(__x86_64__)
HG_DECLARE(avx2)
HG_DECLARE(avx512)
#else
HG_DECLARE(portable)
#endif
#undef HG_DECLARE


// The colour field's MLPs (mlp.cpp, mlp_kernels.h): code (N, code_dim) -> h1 -> h2 (ReLU, 64
// each); h3 = ReLU(sh (N, 16) @ Wd^T + h2 @ M^T); s = sigmoid(h3 @ W2^T) (N, 3);
// out = s * scale - shift. Weights as nn.Linear stores them (out, in); *t are transposes.
constexpr int kMlpHidden = 64;  // hidden width (the field's only one)
constexpr int kMlpDir = 16;     // direction code width (degree-3 SH)
constexpr int kMlpBlock = 64;   // points per block that go through all layers together

struct MlpArgs {
  int code_dim;                          // 16, 32 or 64
  const float* code;                     // (N, code_dim)
  const float* sh;                       // (N, 16)
  const float *w0, *w1, *m, *wd, *w2;    // (64, code_dim), (64, 64), (64, 64), (64, 16), (3, 64)
  const float *w0t, *w1t, *mt, *wdt;     // (code_dim, 64), (64, 64), (64, 64), (16, 64)
  float scale, shift;
  float *h1, *h2, *h3;                   // (N, 64) activations: forward writes, backward reads
  float* s;                              // (N, 3) sigmoid outputs: likewise
  float* out;                            // (N, 3) forward output
  const float* grad;                     // (N, 3) backward: d loss / d out
  float *g_code, *g_sh;                  // (N, code_dim), (N, 16) backward outputs
};

// One thread's weight-gradient sums, laid out as the weights.
struct MlpGrads {
  float *w0, *w1, *m, *wd, *w2;
};

#define MLP_DECLARE(NS)                                                                  \
  namespace NS {                                                                         \
  void mlp_forward_range(const MlpArgs& a, int64_t begin, int64_t end);                  \
  void mlp_backward_range(const MlpArgs& a, int64_t begin, int64_t end, const MlpGrads& g, \
                          float* scratch);                                               \
  }
#if defined(__x86_64__)
MLP_DECLARE(avx2)
MLP_DECLARE(avx512)
#else
MLP_DECLARE(portable)
#endif
#undef MLP_DECLARE

#if defined(__x86_64__)
// Whether the AVX-512 variants of the kernels run: the CPU reports avx512f/bw/dq/vl and
// $SPARSESPLAT_HASHGRID_ISA is not "avx2" (that forces the baseline). hashgrid.cpp.
bool use_avx512_kernels();
#endif
