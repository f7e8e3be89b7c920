// e^x for float without a libm call, so that loops over it vectorise (AVX2: 8 lanes): the rasterizer's per-row
// alphas (rasterize_cpu.cpp) and the drift terms (drift_cpu.cpp).
// Cephes' expf: Cody-Waite reduction by ln 2, degree-6 polynomial, scale by 2^n through the exponent bits;
// relative error ~1e-7 for x in [-87, 88], the range it clamps to (callers that need e^x outside it, or NaN, check
// their inputs).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace abcgs {

inline float exp_fast(float x) {
  x = std::min(88.0f, std::max(-87.0f, x));
  const float n = std::floor(x * 1.44269504088896341f + 0.5f);
  const float f = x - n * 0.693359375f + n * 2.12194440e-4f;
  const float z = f * f;
  const float p = (((((1.9875691500e-4f * f + 1.3981999507e-3f) * f + 8.3334519073e-3f) * f + 4.1665795894e-2f) * f +
                    1.6666665459e-1f) * f + 5.0000001201e-1f) * z + f + 1.0f;
  const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof(scale));
  return p * scale;
}

}  // namespace abcgs
