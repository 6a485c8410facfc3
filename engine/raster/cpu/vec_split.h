// A tile row split into kParts native vectors, and the operators the kernels use on it, each
// defined part by part: the vector layers of targets with no register as wide as a row
// (kernels.h's AVX2 layer, two ymm halves; vec_portable.h, four 16-byte quarters).
//
// Included by those layers inside the kernels' namespace, after they define kParts and the
// part types pf (float) and pi (int32). Defines the row types vf / vi, their arithmetic,
// comparison and integer operators, conversions and reinterpretations. Leaves RASTER_PARTWISE
// defined for the layer's own part-wise functions; the layer undefines it.
#pragma once

struct vf {
  pf h[kParts];
  float& operator[](int i) { return reinterpret_cast<float*>(h)[i]; }
  float operator[](int i) const { return reinterpret_cast<const float*>(h)[i]; }
};
struct vi {
  pi h[kParts];
  int32_t& operator[](int i) { return reinterpret_cast<int32_t*>(h)[i]; }
  int32_t operator[](int i) const { return reinterpret_cast<const int32_t*>(h)[i]; }
};

// r.h[k] = expr for each part k (expr reads the k of the enclosing loop); GCC unrolls it.
#define RASTER_PARTWISE(T, expr)                    \
  T r;                                              \
  for (int k = 0; k < kParts; ++k) r.h[k] = (expr); \
  return r

#define RASTER_VF_BINOP(op)                                                             \
  static inline vf operator op(vf a, vf b) { RASTER_PARTWISE(vf, a.h[k] op b.h[k]); } \
  static inline vf operator op(vf a, float b) { RASTER_PARTWISE(vf, a.h[k] op b); }   \
  static inline vf operator op(float a, vf b) { RASTER_PARTWISE(vf, a op b.h[k]); }   \
  static inline vf& operator op##=(vf & a, vf b) { return a = a op b; }
RASTER_VF_BINOP(+)
RASTER_VF_BINOP(-)
RASTER_VF_BINOP(*)
RASTER_VF_BINOP(/)
#undef RASTER_VF_BINOP
static inline vf operator-(vf a) { RASTER_PARTWISE(vf, -a.h[k]); }

#define RASTER_VF_CMP(op)                                                               \
  static inline vi operator op(vf a, vf b) { RASTER_PARTWISE(vi, a.h[k] op b.h[k]); } \
  static inline vi operator op(vf a, float b) { RASTER_PARTWISE(vi, a.h[k] op b); }
RASTER_VF_CMP(<)
RASTER_VF_CMP(>)
RASTER_VF_CMP(<=)
RASTER_VF_CMP(>=)
#undef RASTER_VF_CMP

static inline vi operator&(vi a, vi b) { RASTER_PARTWISE(vi, a.h[k] & b.h[k]); }
static inline vi& operator&=(vi& a, vi b) { return a = a & b; }
static inline vi operator~(vi a) { RASTER_PARTWISE(vi, ~a.h[k]); }
static inline vi operator+(vi a, vi b) { RASTER_PARTWISE(vi, a.h[k] + b.h[k]); }
static inline vi operator<<(vi a, int s) { RASTER_PARTWISE(vi, a.h[k] << s); }
static inline vi operator<(vi a, vi b) { RASTER_PARTWISE(vi, a.h[k] < b.h[k]); }
static inline vi operator+(vi a, int32_t b) { RASTER_PARTWISE(vi, a.h[k] + b); }

static inline vi to_int(vf x) { RASTER_PARTWISE(vi, __builtin_convertvector(x.h[k], pi)); }
static inline vf to_float(vi x) { RASTER_PARTWISE(vf, __builtin_convertvector(x.h[k], pf)); }
static inline vi bits_of(vf x) { RASTER_PARTWISE(vi, (pi)x.h[k]); }
static inline vf from_bits(vi x) { RASTER_PARTWISE(vf, (pf)x.h[k]); }
