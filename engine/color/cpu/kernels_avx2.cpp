// Level kernels for the x86-64-v3 baseline (AVX2 + FMA, the flags given to the whole build).
// Empty on other CPUs (kernels_portable.cpp builds there; the build lists the same sources).
#if defined(__x86_64__)
#define HG_NS avx2
#include "kernels.h"
#endif
