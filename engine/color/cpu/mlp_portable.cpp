// Fused MLP kernels in GCC generic vectors (no intrinsics) for CPUs other than x86 (NEON on
// aarch64). Empty on x86, which runs the AVX2 and AVX-512 builds.
#if !defined(__x86_64__)
#define MLP_NS portable
#define MLP_AVX512 0
#define MLP_PORTABLE 1
#include "mlp_kernels.h"
#endif
