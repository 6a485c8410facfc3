// Tile kernels in GCC's generic vectors only (vec_portable.h): the variant every CPU can build,
// and the only one on non-x86 CPUs (NEON on aarch64). On x86 it is built and selectable too
// (SPARSESPLAT_RASTER_ISA=portable), so its numerics are tested natively; raster.cpp never picks
// it there by default.
#define RASTER_NS portable
#define RASTER_AVX512 0
#define RASTER_PORTABLE 1
#include "kernels.h"
