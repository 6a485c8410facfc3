// Fused MLP kernels for the x86-64-v3 baseline (AVX2 + FMA, the flags given to the whole build).
// Empty on other CPUs (mlp_portable.cpp builds there; the build lists the same sources).
#if defined(__x86_64__)
#define MLP_NS avx2
#define MLP_AVX512 0
#include "mlp_kernels.h"
#endif
