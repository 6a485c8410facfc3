// Flush-to-zero / denormals-are-zero on every compute thread (the MXCSR register is per thread).
// torch.set_flush_denormal sets it on the calling thread only, while the work (fused Adam, the
// kernels here, the rasterizer's loops) runs on the OpenMP team's threads.
#include <ATen/Parallel.h>
#include <omp.h>
#include <xmmintrin.h>

#include <algorithm>

namespace {

constexpr unsigned kFtzDaz = 0x8040;  // MXCSR bits 15 (flush to zero) and 6 (denormals are zero)

void apply(bool on) {
  const unsigned csr = _mm_getcsr();
  _mm_setcsr(on ? (csr | kFtzDaz) : (csr & ~kFtzDaz));
}

}  // namespace

// Sets (on) or clears both bits on the calling thread and on each thread of the OpenMP team at
// the current thread count; returns whether the calling thread had both set before.
bool set_flush_denormal_all(bool on) {
  const bool before = (_mm_getcsr() & kFtzDaz) == kFtzDaz;
  apply(on);
  const int n = std::max(1, at::get_num_threads());
  // at::parallel_for over n one-element chunks with grain 1 gives each team thread one chunk.
  at::parallel_for(0, n, 1, [&](int64_t, int64_t) { apply(on); });
#pragma omp parallel num_threads(n)
  apply(on);
  return before;
}

// Whether the calling thread flushes denormals (both bits set).
bool flush_denormal_enabled() { return (_mm_getcsr() & kFtzDaz) == kFtzDaz; }
