// Finite-difference kernels of the active surface engine (core/active/narrow_band.cpp, motion.cpp, stepper.cpp), on a
// dense apron array with strides. Internal to core; not part of the public API.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "core/active/sparse_grid.h"

#if defined(__GNUC__)
#define SURFACER_ALWAYS_INLINE inline __attribute__((always_inline))
#else
#define SURFACER_ALWAYS_INLINE inline
#endif

namespace surfacer::active_detail {

// Mean curvature kappa = div(n), n = -grad f / |grad f| (ALGORITHMS §4), by central differences at f[0] with strides
// (sx, sy, sz); 0 where |grad f| vanishes. Not clamped.
inline double curvature(const float* f, int sx, int sy, int sz, double inv_h) {
  const double c = f[0];
  const double fx = 0.5 * (f[sx] - f[-sx]), fy = 0.5 * (f[sy] - f[-sy]), fz = 0.5 * (f[sz] - f[-sz]);
  const double fxx = f[sx] - 2.0 * c + f[-sx], fyy = f[sy] - 2.0 * c + f[-sy], fzz = f[sz] - 2.0 * c + f[-sz];
  const double fxy = 0.25 * (f[sx + sy] - f[sx - sy] - f[-sx + sy] + f[-sx - sy]);
  const double fxz = 0.25 * (f[sx + sz] - f[sx - sz] - f[-sx + sz] + f[-sx - sz]);
  const double fyz = 0.25 * (f[sy + sz] - f[sy - sz] - f[-sy + sz] + f[-sy - sz]);
  const double g2 = fx * fx + fy * fy + fz * fz;
  if (g2 < 1e-20) return 0.0;
  const double num = fx * fx * (fyy + fzz) + fy * fy * (fxx + fzz) + fz * fz * (fxx + fyy) - 2.0 * fx * fy * fxy -
                     2.0 * fx * fz * fxz - 2.0 * fy * fz * fyz;
  // Differences are in grid units: kappa = -num / (g2^1.5) / h.
  return -num / (g2 * std::sqrt(g2)) * inv_h;
}

// Per-thread scratch arrays of the engine's passes (aprons, stage rates): slot in [0, 6), at least `size` floats.
inline float* scratch(int slot, std::size_t size) {
  thread_local std::vector<float> buffers[6];
  if (buffers[slot].size() < size) buffers[slot].resize(size);
  return buffers[slot].data();
}

inline constexpr int kApronSide = sparse::apron_side<3>();  // a block with the 3-node WENO apron

// Band bits over a dense apron of side S (G >= 1 ghost nodes): band[i] = |f| < 1 or a 6-neighbour has the other
// sign, for the (S - 2)^3 interior positions (index (x + 1) + (S - 2) ((y + 1) + (S - 2) (z + 1)) for apron-interior
// coordinates x, y, z in [-1, S - 3) relative to the first interior node).
template <int S>
inline void band_bits(const float* __restrict ap, unsigned char* __restrict band) {
  constexpr int R = S - 2;
  unsigned char in[S * S * S];
  for (int i = 0; i < S * S * S; ++i) in[i] = ap[i] > 0.0f;
  for (int z = 1; z < S - 1; ++z)
    for (int y = 1; y < S - 1; ++y) {
      const unsigned char* c = in + S * (y + S * z);
      const float* v = ap + S * (y + S * z);
      unsigned char* out = band + R * ((y - 1) + R * (z - 1)) - 1;
      for (int x = 1; x < S - 1; ++x) {
        const unsigned char m = c[x];
        const unsigned char diff =
            (c[x + 1] ^ m) | (c[x - 1] ^ m) | (c[x + S] ^ m) | (c[x - S] ^ m) | (c[x + S * S] ^ m) | (c[x - S * S] ^ m);
        const float a = v[x] < 0.0f ? -v[x] : v[x];
        out[x] = static_cast<unsigned char>(diff | (a < 1.0f));
      }
    }
}

// --- Dense block kernels (core/active/kernels.cpp) ---------------------------------------------------------
// They run over all sparse::kBlockNodes nodes of a block (x fastest) from its 3-node apron (side kApronSide); callers
// keep the results of active nodes. Derivatives are one-sided HJ-WENO5 (Jiang & Peng 2000) with WENO-Z weights (Borges
// et al. 2008), taken on grid-unit differences (values O(1), so WENO's epsilon 1e-6 stays meaningful in float).

// Normal speed: rate = s |grad f| (units of f per time) with Godunov's Hamiltonian for phi_t + s |grad phi| = 0,
// phi = -f: with sigma = sign(s), per axis max(min(sigma D-f, 0)^2, max(sigma D+f, 0)^2).
void normal_rate_block(const float* ap, const float* speed, float inv_h, float* rate);

// Advection: rate = -u . grad f, upwind per axis; u given per node (3 arrays).
void advect_rate_block(const float* ap, const float* ux, const float* uy, const float* uz, float inv_h, float* rate);

// Both (the control terms on top of an advection): rate = -u . grad f + s |grad f|, each term upwinded on its own as
// above, from one WENO pass; equal bit for bit to advect_rate_block's rate plus normal_rate_block's.
void advect_normal_rate_block(const float* ap, const float* ux, const float* uy, const float* uz, const float* speed,
                              float inv_h, float* rate);

}  // namespace surfacer::active_detail
