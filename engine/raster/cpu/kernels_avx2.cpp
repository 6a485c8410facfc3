// Tile kernels for the x86-64-v3 baseline (AVX2 + FMA, the flags given to the whole build).
// Empty on other CPUs (the build lists the same sources everywhere).
#if defined(__x86_64__)
#define RASTER_NS avx2
#define RASTER_AVX512 0
#include "kernels.h"
#endif
