// Level kernels for AVX-512 CPUs; only called when the CPU reports avx512f/bw/dq/vl at run time.
// Empty on other CPUs.
#if defined(__x86_64__)
#pragma GCC target("avx512f,avx512bw,avx512dq,avx512vl,prefer-vector-width=512")
#define HG_NS avx512
#include "kernels.h"
#endif
