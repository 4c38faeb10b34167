// Float bit access and a polynomial log2 shared by the kernels (header-only, inline: the callers'
// loops are built for several ISAs and vectorise them).
#pragma once
#include <cstdint>
#include <cstring>

namespace ibr {

inline float AsFloat(std::uint32_t b) {
  float v;
  std::memcpy(&v, &b, 4);
  return v;
}
inline std::uint32_t AsBits(float v) {
  std::uint32_t b;
  std::memcpy(&b, &v, 4);
  return b;
}

// log2(x) for a positive normal float (finite garbage for 0, subnormals, inf and NaN, which the
// callers select away): x = m 2^e with m in [sqrt(1/2), sqrt(2)), log2(m) = u q(u), u = m - 1,
// q of degree 8 fitted (Chebyshev, least squares) on that range: absolute error 3.5e-8, below
// float32's rounding of the result.
inline float Log2Pos(float x) {
  const std::uint32_t bits = AsBits(x);
  const std::uint32_t mant = bits & 0x007fffffu;
  const bool big = mant > 0x003504f3u;  // m > sqrt(2): take m / 2 and e + 1
  const int e = static_cast<int>((bits >> 23) & 0xffu) - 127 + (big ? 1 : 0);
  const float u = AsFloat(mant | (big ? 0x3f000000u : 0x3f800000u)) - 1.0f;
  const float q = 1.44269501f + u * (-0.72134744f + u * (0.480907938f + u * (-0.36069331f + u * (0.288005203f +
                  u * (-0.239245699f + u * (0.215087393f + u * (-0.204805449f + u * 0.124539019f)))))));
  return static_cast<float>(e) + u * q;
}

}  // namespace ibr
