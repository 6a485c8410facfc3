// Fused MLP kernels for AVX-512 CPUs; only called when the CPU reports avx512f/bw/dq/vl.
// Empty on other CPUs.
#if defined(__x86_64__)
#pragma GCC target("avx512f,avx512bw,avx512dq,avx512vl,prefer-vector-width=512")
#define MLP_NS avx512
#define MLP_AVX512 1
#include "mlp_kernels.h"
#endif
