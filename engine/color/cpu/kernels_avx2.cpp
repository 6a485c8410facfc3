// Level kernels for the x86-64-v3 baseline (AVX2 + FMA, the flags given to the whole build).
#define HG_NS avx2
#include "kernels.h"
