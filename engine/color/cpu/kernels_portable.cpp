// Level kernels for CPUs other than x86 (NEON on aarch64): kernels.h has no intrinsics, so this
// is the same source under the architecture's baseline flags. Empty on x86, which runs the AVX2
// and AVX-512 builds of it.
#if !defined(__x86_64__)
#define HG_NS portable
#include "kernels.h"
#endif
