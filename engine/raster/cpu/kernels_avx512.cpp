// Tile kernels for AVX-512 CPUs; only called when the CPU reports avx512f/bw/dq/vl at run time.
// Empty on other CPUs (the build lists the same sources everywhere).
#if defined(__x86_64__)
#pragma GCC target("avx512f,avx512bw,avx512dq,avx512vl,prefer-vector-width=512")
#define RASTER_NS avx512
#define RASTER_AVX512 1
#include "kernels.h"
#endif
