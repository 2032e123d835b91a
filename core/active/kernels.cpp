// Dense block kernels of the active surface engine (declared in core/active/schemes.h).
//
// Rows of 8 nodes are processed as 8-float vectors (GCC/Clang vector extensions). On x86-64 Linux with GCC the
// kernels are compiled twice, for AVX2 and for the baseline, and picked at load time (target_clones); both run the
// same IEEE operations in the same order (no FMA contraction), so results do not depend on the CPU.
#include <cstddef>
#include <cstring>

#include "core/active/schemes.h"

// Not under ThreadSanitizer: the clones' resolver runs while the program is loaded, before the sanitizer's runtime,
// and its instrumented code crashes there.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && \
    !defined(__SANITIZE_THREAD__)
#define SURFACER_KERNEL_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define SURFACER_KERNEL_CLONES
#endif

namespace surfacer::active_detail {
namespace {

typedef float v8f __attribute__((vector_size(32)));
// Unaligned, aliasing view for loads and stores. (Vectors are passed by reference below: by value GCC notes an
// ABI change for 32-byte arguments without AVX, although every helper is inlined.)
typedef float v8f_u __attribute__((vector_size(32), aligned(4), may_alias));

#define SURFACER_LOAD8(p) (*reinterpret_cast<const v8f_u*>(p))
#define SURFACER_STORE8(p, v) (*reinterpret_cast<v8f_u*>(p) = (v))

// HJ-WENO5 (Jiang & Peng 2000) one-sided derivative from the grid-unit differences v1..v5 ordered toward the upwind
// side (for D- at node i: D+f at i-3 .. i+1; for D+: at i+2 .. i-2), with WENO-Z weights (Borges, Carmona, Costa &
// Don 2008): alpha_k = d_k (1 + (tau / s_k)^2), tau = |s1 - s3|, d = (0.1, 0.6, 0.3), Jiang & Peng's smoothness
// indicators s_k and epsilon 1e-6. Less dissipative than the classic weights at extrema and under-resolved
// features: thin sheets lose markedly less volume in the Enright test.
SURFACER_ALWAYS_INLINE void weno5v(const v8f& v1, const v8f& v2, const v8f& v3, const v8f& v4, const v8f& v5,
                                   v8f& out) {
  const v8f p1 = v1 * (1.0f / 3.0f) - v2 * (7.0f / 6.0f) + v3 * (11.0f / 6.0f);
  const v8f p2 = -v2 * (1.0f / 6.0f) + v3 * (5.0f / 6.0f) + v4 * (1.0f / 3.0f);
  const v8f p3 = v3 * (1.0f / 3.0f) + v4 * (5.0f / 6.0f) - v5 * (1.0f / 6.0f);
  const v8f a1 = v1 - 2.0f * v2 + v3, b1 = v1 - 4.0f * v2 + 3.0f * v3;
  const v8f a2 = v2 - 2.0f * v3 + v4, b2 = v2 - v4;
  const v8f a3 = v3 - 2.0f * v4 + v5, b3 = 3.0f * v3 - 4.0f * v4 + v5;
  const v8f s1 = (13.0f / 12.0f) * a1 * a1 + 0.25f * b1 * b1 + 1e-6f;
  const v8f s2 = (13.0f / 12.0f) * a2 * a2 + 0.25f * b2 * b2 + 1e-6f;
  const v8f s3 = (13.0f / 12.0f) * a3 * a3 + 0.25f * b3 * b3 + 1e-6f;
  const v8f tau = s1 > s3 ? s1 - s3 : s3 - s1;
  const v8f r1 = tau / s1, r2 = tau / s2, r3 = tau / s3;
  const v8f w1 = 0.1f * (1.0f + r1 * r1), w2 = 0.6f * (1.0f + r2 * r2), w3 = 0.3f * (1.0f + r3 * r3);
  out = (w1 * p1 + w2 * p2 + w3 * p3) / (w1 + w2 + w3);
}

// Left- and right-biased derivatives (grid units) of the 8 nodes of a row starting at f, along stride st.
SURFACER_ALWAYS_INLINE void weno_row(const float* f, std::ptrdiff_t st, v8f& dm, v8f& dp) {
  const v8f fm3 = SURFACER_LOAD8(f - 3 * st), fm2 = SURFACER_LOAD8(f - 2 * st), fm1 = SURFACER_LOAD8(f - st);
  const v8f f0 = SURFACER_LOAD8(f);
  const v8f fp1 = SURFACER_LOAD8(f + st), fp2 = SURFACER_LOAD8(f + 2 * st), fp3 = SURFACER_LOAD8(f + 3 * st);
  const v8f d0 = fm2 - fm3, d1 = fm1 - fm2, d2 = f0 - fm1, d3 = fp1 - f0, d4 = fp2 - fp1, d5 = fp3 - fp2;
  weno5v(d0, d1, d2, d3, d4, dm);
  weno5v(d5, d4, d3, d2, d1, dp);
}

constexpr std::ptrdiff_t kS = kApronSide;
constexpr std::ptrdiff_t kRow = sparse::kBlockSize;  // a row of a block along x: one v8f
static_assert(sizeof(v8f) == kRow * sizeof(float), "a block row is one 8-float vector");

// Adds to g2 the square of Godunov's upwind difference along one axis for the sign `sigma` of the normal speed.
SURFACER_ALWAYS_INLINE void add_godunov_square(const v8f& sigma, const v8f& dm, const v8f& dp, v8f& g2) {
  const v8f zero = {0, 0, 0, 0, 0, 0, 0, 0};
  const v8f sdm = sigma * dm, sdp = sigma * dp;
  const v8f a = sdm < zero ? sdm : zero, b = sdp > zero ? sdp : zero;
  const v8f a2 = a * a, b2 = b * b;
  g2 += a2 > b2 ? a2 : b2;
}

// The square root of every lane of x into out (scalar sqrt: the same IEEE result in every build).
SURFACER_ALWAYS_INLINE void sqrt_lanes(const v8f& x, v8f& out) {
  float tmp[kRow];
  SURFACER_STORE8(tmp, x);
  for (int k = 0; k < kRow; ++k) tmp[k] = std::sqrt(tmp[k]);
  out = SURFACER_LOAD8(tmp);
}

const float* row_start(const float* ap, std::ptrdiff_t y, std::ptrdiff_t z) {
  return ap + 3 + kS * ((y + 3) + kS * (z + 3));
}

}  // namespace

SURFACER_KERNEL_CLONES void normal_rate_block(const float* ap, const float* speed, float inv_h, float* rate) {
  const std::ptrdiff_t strides[3] = {1, kS, kS * kS};
  const v8f zero = {0, 0, 0, 0, 0, 0, 0, 0}, one = {1, 1, 1, 1, 1, 1, 1, 1};
  for (std::ptrdiff_t r = 0; r < sparse::kBlockRows; ++r) {
    const float* row = row_start(ap, r & sparse::kBlockMask, r >> sparse::kBlockLog2);
    const v8f s = SURFACER_LOAD8(speed + kRow * r);
    const v8f sigma = s > 0.0f ? one : -one;
    v8f g2 = zero;
    for (const std::ptrdiff_t st : strides) {
      v8f dm, dp;
      weno_row(row, st, dm, dp);
      add_godunov_square(sigma, dm, dp, g2);
    }
    v8f g;
    sqrt_lanes(g2, g);
    SURFACER_STORE8(rate + kRow * r, s * g * inv_h);
  }
}

SURFACER_KERNEL_CLONES void advect_rate_block(const float* ap, const float* ux, const float* uy, const float* uz,
                                              float inv_h, float* rate) {
  const std::ptrdiff_t strides[3] = {1, kS, kS * kS};
  const float* u[3] = {ux, uy, uz};
  for (std::ptrdiff_t r = 0; r < sparse::kBlockRows; ++r) {
    const float* row = row_start(ap, r & sparse::kBlockMask, r >> sparse::kBlockLog2);
    v8f acc = {0, 0, 0, 0, 0, 0, 0, 0};
    for (int a = 0; a < 3; ++a) {
      v8f dm, dp;
      weno_row(row, strides[a], dm, dp);
      const v8f ua = SURFACER_LOAD8(u[a] + kRow * r);
      acc -= ua * (ua > 0.0f ? dm : dp);
    }
    SURFACER_STORE8(rate + kRow * r, acc * inv_h);
  }
}

// The advection and the normal speed from one set of WENO differences: the same operations as advect_rate_block
// followed by normal_rate_block and a sum, in the same order, so the result equals that sum bit for bit.
SURFACER_KERNEL_CLONES void advect_normal_rate_block(const float* ap, const float* ux, const float* uy, const float* uz,
                                                     const float* speed, float inv_h, float* rate) {
  const std::ptrdiff_t strides[3] = {1, kS, kS * kS};
  const float* u[3] = {ux, uy, uz};
  const v8f zero = {0, 0, 0, 0, 0, 0, 0, 0}, one = {1, 1, 1, 1, 1, 1, 1, 1};
  for (std::ptrdiff_t r = 0; r < sparse::kBlockRows; ++r) {
    const float* row = row_start(ap, r & sparse::kBlockMask, r >> sparse::kBlockLog2);
    const v8f s = SURFACER_LOAD8(speed + kRow * r);
    const v8f sigma = s > 0.0f ? one : -one;
    v8f acc = zero, g2 = zero;
    for (int a = 0; a < 3; ++a) {
      v8f dm, dp;
      weno_row(row, strides[a], dm, dp);
      const v8f ua = SURFACER_LOAD8(u[a] + kRow * r);
      acc -= ua * (ua > 0.0f ? dm : dp);
      add_godunov_square(sigma, dm, dp, g2);
    }
    v8f g;
    sqrt_lanes(g2, g);
    const v8f advect_rate = acc * inv_h;
    const v8f normal_rate = s * g * inv_h;
    SURFACER_STORE8(rate + kRow * r, advect_rate + normal_rate);
  }
}

#undef SURFACER_LOAD8
#undef SURFACER_STORE8

}  // namespace surfacer::active_detail
