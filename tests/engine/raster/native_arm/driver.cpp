// A torch-free driver of the rasterizer's portable tile kernels (engine/raster/cpu/kernels.h
// built as kernels_portable.cpp), so they can run where torch cannot: compiled for aarch64 by a
// cross g++ and run under qemu-user (tests/engine/raster/arm64.py, test_arm64_emulated.py).
//
// Usage: driver IN OUT. IN holds a header of kHeaderInts int32 values, then the mode's arrays
// back to back (float32 / int32, native byte order; the x86 test writes them from the state its
// own native forward built: depth-sorted records, tile lists and offsets). The driver runs every
// tile of the image, one thread (the kernels have none of their own), and writes the mode's
// outputs to OUT, back to back:
//   forward:    recs, feats, list, offsets, bg
//               -> image (C,H,W), depth, alpha, t_final (H,W) f32, last (H,W) i32, stats 2 i64
//   backward:   recs, feats, list, offsets, bg, t_final, last, v_image, v_depth, v_alpha,
//               [v_depth_opacity]
//               -> grads (M, C + kGradFixed) f32, per record (depth order), as raster.cpp's
//                  per-thread buffers before its reduction
//   reciprocal: x (n), estimate (n) -> 1 / x (n) by the kernels' refinement
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "common.h"

namespace {

constexpr int32_t kMagic = 0x53525344;  // "DSRS"
constexpr int kHeaderInts = 16;
enum Mode : int32_t { kForward = 0, kBackward = 1, kReciprocal = 2 };
enum Flag : int32_t { kHasDepthOpacity = 1, kGeometry = 2 };

// The header's fields, by position.
struct Header {
  int32_t magic, mode, width, height, channels, records, list_len, flags, count;
};

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "driver: %s\n", what);
  std::exit(2);
}

// Reads the input file's arrays in order.
struct Reader {
  std::vector<char> data;
  size_t at = 0;
  template <class T>
  const T* take(size_t n) {
    const size_t bytes = n * sizeof(T);
    if (at + bytes > data.size()) fail("input file shorter than its header says");
    const T* p = reinterpret_cast<const T*>(data.data() + at);
    at += bytes;
    return p;
  }
};

// A 64-byte aligned copy (records are cache-line structs; scratch must be aligned).
template <class T>
T* aligned_copy(const T* src, size_t n) {
  size_t bytes = ((n * sizeof(T) + 63) / 64) * 64;
  T* p = static_cast<T*>(std::aligned_alloc(64, bytes > 0 ? bytes : 64));
  if (!p) fail("out of memory");
  if (n) std::memcpy(p, src, n * sizeof(T));
  return p;
}

float* aligned_floats(size_t n) {
  size_t bytes = ((n * sizeof(float) + 63) / 64) * 64;
  float* p = static_cast<float*>(std::aligned_alloc(64, bytes > 0 ? bytes : 64));
  if (!p) fail("out of memory");
  std::memset(p, 0, bytes > 0 ? bytes : 64);
  return p;
}

void write_all(std::FILE* f, const void* p, size_t bytes) {
  if (bytes && std::fwrite(p, 1, bytes, f) != bytes) fail("cannot write the output file");
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) fail("usage: driver IN OUT");
  Reader in;
  {
    std::FILE* f = std::fopen(argv[1], "rb");
    if (!f) fail("cannot open the input file");
    char buf[1 << 16];
    size_t got;
    while ((got = std::fread(buf, 1, sizeof buf, f)) > 0) in.data.insert(in.data.end(), buf, buf + got);
    std::fclose(f);
  }
  Header h;
  const int32_t* raw = in.take<int32_t>(kHeaderInts);
  std::memcpy(&h, raw, sizeof h);
  if (h.magic != kMagic) fail("not a driver input file");
  std::FILE* out = std::fopen(argv[2], "wb");
  if (!out) fail("cannot open the output file");

  if (h.mode == kReciprocal) {
    const float* x = in.take<float>(h.count);
    const float* r = in.take<float>(h.count);
    std::vector<float> y(h.count);
    portable::reciprocal(x, r, y.data(), h.count);
    write_all(out, y.data(), y.size() * sizeof(float));
    std::fclose(out);
    return 0;
  }

  const int W = h.width, H = h.height, C = h.channels, M = h.records;
  const int tiles_x = (W + TILE - 1) / TILE, tiles_y = (H + TILE - 1) / TILE;
  const int n_tiles = tiles_x * tiles_y;
  const size_t HW = (size_t)H * W;
  const int rec_floats = (int)(sizeof(GaussRec) / sizeof(float));
  GaussRec* recs =
      reinterpret_cast<GaussRec*>(aligned_copy(in.take<float>((size_t)M * rec_floats), (size_t)M * rec_floats));
  const float* feats = in.take<float>((size_t)M * C);
  const int32_t* list = in.take<int32_t>(h.list_len);
  const int32_t* offsets = in.take<int32_t>(n_tiles + 1);
  const float* bg = in.take<float>(C);

  if (h.mode == kForward) {
    std::vector<float> image((size_t)C * HW), depth(HW), alpha(HW), t_final(HW);
    std::vector<int32_t> last(HW);
    std::vector<int64_t> evaluated(n_tiles), blended(n_tiles);
    TileFwd a{recs, feats, list, offsets, tiles_x, W, H, C, bg, image.data(), depth.data(),
              alpha.data(), t_final.data(), last.data(), evaluated.data(), blended.data()};
    float* scratch = aligned_floats((size_t)(C + 1) * TILE * TILE);
    for (int t = 0; t < n_tiles; ++t) portable::forward_tile(a, t % tiles_x, t / tiles_x, scratch);
    int64_t stats[2] = {0, 0};
    for (int t = 0; t < n_tiles; ++t) {
      stats[0] += evaluated[t];
      stats[1] += blended[t];
    }
    write_all(out, image.data(), image.size() * sizeof(float));
    write_all(out, depth.data(), HW * sizeof(float));
    write_all(out, alpha.data(), HW * sizeof(float));
    write_all(out, t_final.data(), HW * sizeof(float));
    write_all(out, last.data(), HW * sizeof(int32_t));
    write_all(out, stats, sizeof stats);
  } else if (h.mode == kBackward) {
    const float* t_final = in.take<float>(HW);
    const int32_t* last = in.take<int32_t>(HW);
    const float* v_image = in.take<float>((size_t)C * HW);
    const float* v_depth = in.take<float>(HW);
    const float* v_alpha = in.take<float>(HW);
    const float* v_dop = (h.flags & kHasDepthOpacity) ? in.take<float>(HW) : nullptr;
    const int S = C + kGradFixed;
    std::vector<float> grads((size_t)M * S, 0.0f);
    TileBwd a{recs, feats, list, offsets, tiles_x, W, H, C, bg, t_final, last, v_image,
              v_depth, v_alpha, v_dop, (h.flags & kGeometry) != 0};
    float* scratch = aligned_floats((size_t)((C + 1) * TILE + S + TILE) * TILE);
    for (int t = 0; t < n_tiles; ++t)
      portable::backward_tile(a, t % tiles_x, t / tiles_x, scratch, grads.data());
    write_all(out, grads.data(), grads.size() * sizeof(float));
  } else {
    fail("unknown mode");
  }
  if (std::fclose(out) != 0) fail("cannot write the output file");
  return 0;
}
