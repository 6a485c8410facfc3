// Flush-to-zero / denormals-are-zero on every compute thread (the MXCSR register is per thread;
// on aarch64 the FPCR's FZ bit, likewise per thread).
// torch.set_flush_denormal sets it on the calling thread only, while the work (fused Adam, the
// kernels here, the rasterizer's loops) runs on the OpenMP team's threads.
#include <ATen/Parallel.h>
#include <omp.h>
#if defined(__x86_64__)
#include <xmmintrin.h>
#endif

#include <algorithm>

namespace {

#if defined(__x86_64__)
constexpr unsigned kFtzDaz = 0x8040;  // MXCSR bits 15 (flush to zero) and 6 (denormals are zero)

bool enabled() { return (_mm_getcsr() & kFtzDaz) == kFtzDaz; }

void apply(bool on) {
  const unsigned csr = _mm_getcsr();
  _mm_setcsr(on ? (csr | kFtzDaz) : (csr & ~kFtzDaz));
}
#elif defined(__aarch64__)
// FPCR bit 24 (FZ): denormal inputs and results of float operations flush to zero (AArch64 has
// one bit for both of x86's).
constexpr unsigned long kFz = 1ul << 24;

bool enabled() { return (__builtin_aarch64_get_fpcr64() & kFz) != 0; }

void apply(bool on) {
  const unsigned long fpcr = __builtin_aarch64_get_fpcr64();
  __builtin_aarch64_set_fpcr64(on ? (fpcr | kFz) : (fpcr & ~kFz));
}
#else
// No known control register: the mode stays the CPU's default (denormals kept).
bool enabled() { return false; }
void apply(bool) {}
#endif

}  // namespace

// Sets (on) or clears both bits on the calling thread and on each thread of the OpenMP team at
// the current thread count; returns whether the calling thread had both set before.
bool set_flush_denormal_all(bool on) {
  const bool before = enabled();
  apply(on);
  const int n = std::max(1, at::get_num_threads());
  // at::parallel_for over n one-element chunks with grain 1 gives each team thread one chunk.
  at::parallel_for(0, n, 1, [&](int64_t, int64_t) { apply(on); });
#pragma omp parallel num_threads(n)
  apply(on);
  return before;
}

// Whether the calling thread flushes denormals (both bits set).
bool flush_denormal_enabled() { return enabled(); }
