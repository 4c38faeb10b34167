// The project's colour conventions, one module for every family: colour is float32 linear light
// (RGB, any range) inside the engine; stored and displayed colour is sRGB (IEC 61966-2-1), decoded
// on read and encoded on write; 8-bit colour is the sRGB code value / 255. The curves exist once,
// here: the exported functions for whole arrays and single values, and the inline forms
// (namespace colour) for the row loops of kernels that fuse the curve into their own passes.
#pragma once
#include <cstdint>

#include "ibr/fastmath.h"

namespace ibr {
namespace colour {

// c ? a : b on the bits. Every select and comparison of the display curve is done on integers:
// under GCC's default -ftrapping-math a float comparison blocks if-conversion, and the row loops
// would not be vectorised (measured 3.5x slower).
inline float Select(bool c, float a, float b) {
  const std::uint32_t m = 0u - static_cast<std::uint32_t>(c);
  return AsFloat((AsBits(a) & m) | (AsBits(b) & ~m));
}

// 2^y for |y| < 2^22: 2^n 2^f, n = round(y) (by adding 1.5 * 2^23), f in [-1/2, 1/2], 2^f by its
// Taylor series to f^7 (remainder < 2e-9). n is clamped to [-126, 128] on integers: n = 128 is the
// bit pattern of +inf (overflow); results below 2^-126 are not needed here.
inline float Exp2(float y) {
  constexpr float kMagic = 12582912.0f;
  const float r = y + kMagic;
  const float n_f = r - kMagic;
  int n = static_cast<int>(AsBits(r) & 0x007fffffu) - 0x00400000;
  n = n < -126 ? -126 : n;
  n = n > 128 ? 128 : n;
  const float f = (y - n_f) * 0.693147181f;  // f ln 2, |.| <= 0.347
  const float p = 1.0f + f * (1.0f + f * (0.5f + f * (1.0f / 6 + f * (1.0f / 24 + f * (1.0f / 120 +
                  f * (1.0f / 720 + f * (1.0f / 5040)))))));
  return p * AsFloat(static_cast<std::uint32_t>(n + 127) << 23);
}

// The curves. Inline here: the exported SrgbEncode / SrgbDecode may be
// interposed in a shared library (-fPIC), so GCC would not inline them into the row loops.
// The power branch 1.055 a^(1/2.4) - 0.055 for a positive normal a (also below the toe: the nodes of
// the encode table, LinearToSrgbUnclipped, next to the toe).
inline float EncodePower(float a) { return 1.055f * Exp2(Log2Pos(a) * (1.0f / 2.4f)) - 0.055f; }

inline float Encode(float v) {
  const std::uint32_t bits = AsBits(v), abits = bits & 0x7fffffffu;
  const float a = AsFloat(abits);
  const float pw = EncodePower(a);
  float r = Select(abits <= 0x3b4d2e1cu /* 0.0031308f */, 12.92f * a, pw);
  r = Select(abits >= 0x7f800000u, a, r);  // inf and NaN pass through
  return AsFloat(AsBits(r) | (bits & 0x80000000u));
}

inline float Decode(float e) {
  const std::uint32_t bits = AsBits(e), abits = bits & 0x7fffffffu;
  const float a = AsFloat(abits);
  const float pw = Exp2(Log2Pos((a + 0.055f) * (1.0f / 1.055f)) * 2.4f);
  float r = Select(abits <= 0x3d25aee6u /* 0.04045f */, a * (1.0f / 12.92f), pw);
  r = Select(abits >= 0x7f800000u, a, r);
  return AsFloat(AsBits(r) | (bits & 0x80000000u));
}

}  // namespace colour

// The display encoding (metameric synthesis, Walton et al. 2021 sec. 6: "all methods operate on
// non-linear color (subject to display gamma) as they are concerned with perceived contrasts"):
// the sRGB curve (IEC 61966-2-1) extended to every real number, odd (f(-v) = -f(v)) and
// unbounded above with the same formula:
//   SrgbEncode(v) = 12.92 v for |v| <= 0.0031308, sign(v) (1.055 |v|^(1/2.4) - 0.055) beyond;
//   SrgbDecode(e) = e / 12.92 for |e| <= 0.04045, sign(e) ((|e| + 0.055) / 1.055)^2.4 beyond,
// its exact inverse. The powers use a polynomial log2/exp2 with integer selects, so the row loops
// vectorise (relative error < 1e-6 for the encoding, < 1e-5 for the round trip up to 1e6:
// tests/inpaint/test_metameric_kernels.py; 3M values: ~12 ms of one core under load, std::pow-based
// scalar code ~4x that); NaN stays NaN, +-inf stays +-inf, decoding overflows to +inf.
float SrgbEncode(float v);
float SrgbDecode(float e);

// The display encoding of linear colour for images, metrics and 8-bit files (Python:
// ibrtools.imageio.linear_to_srgb): out[i] = SrgbEncode(in[i] clamped to [0, 1]), NaN -> 0, for n
// values (in and out may be the same memory); multithreaded. Within 1e-6 (relative) of the
// IEC 61966-2-1 curve, like SrgbEncode.
void LinearToSrgb(const float* in, float* out, std::int64_t n);

// LinearToSrgb's values as 8-bit codes in one pass (Python: ibrtools.imageio.srgb8, every 8-bit file
// written): out[i] = LinearToSrgb(in[i]) * 255 (float32) rounded to nearest, ties to even: the bits
// of numpy's round(linear_to_srgb(v) * 255) without the float array between; multithreaded.
void LinearToSrgb8(const float* in, std::uint8_t* out, std::int64_t n);

// The sRGB encoding of linear colour for blending in sRGB space (Python: ibrtools.dibr.method.srgb_encode,
// the DIBR inputs with blend_space "srgb"): out[i] = SrgbEncode(max(in[i], 0)) for n values (in and out may
// be the same memory), multithreaded: negative values and -inf -> +0, not clipped above 1 (HDR inputs keep
// their range), +inf stays +inf, NaN stays NaN. In [0, 1] the curve is read from a table of its own values
// indexed by the float's bits (1024 linear segments per binade above 2^-9; 12.92 x at and below the toe,
// as SrgbEncode), ~3x cheaper than evaluating it; SrgbEncode itself above 1 (at least 1: monotonic).
// In [0, 1] within 1e-6 absolute of the float64 curve (measured 1.8e-7; SrgbEncode 1.5e-7), above 1
// SrgbEncode's 1e-6 relative; exact at 0 and 1. avx2: eight values per step with gathers (call it so
// only on a CPU with AVX2); the same bits as the portable loop (no FMA), for any thread count.
void LinearToSrgbUnclipped(const float* in, float* out, std::int64_t n, bool avx2);

// Its inverse for stored colour (Python: ibrtools.imageio.srgb_to_linear): out[i] = in[i] / 12.92
// for in[i] <= 0.04045 (negative values included), ((in[i] + 0.055) / 1.055)^2.4 above (beyond 1
// too); NaN stays NaN. Within 1e-5 (relative) of the exact curve, like SrgbDecode.
void SrgbToLinear(const float* in, float* out, std::int64_t n);

// SrgbToLinear's curve for n values in place on the calling thread, for kernels that decode inside
// their own parallel loops (the sRGB blend space of DIBR: cpp/kernels/dibr/blend.h ResolveBlend). In
// [0, 1] read from a table of SrgbToLinear's own values at 4097 nodes with linear interpolation:
// within 1e-6 (absolute) of SrgbToLinear, exact at the nodes (0 stays 0); outside [0, 1] and NaN
// SrgbToLinear itself. avx2: gathers (call it so only on a CPU with AVX2); the same bits as the
// portable loop (no FMA).
void SrgbToLinearTableRun(float* v, std::int64_t n, bool avx2);

// SrgbEncode for n values on the calling thread (in and out may be the same memory): the row loop of
// kernels that encode inside their own parallel loops (metameric.h MetamericEncode).
void SrgbEncodeRun(const float* in, float* out, std::int64_t n);

// Y'CbCr 4:2:0 or 4:0:0 planes -> linear RGB (Python: ibrtools.formats.yuv.yuv_to_rgb, which defines
// the conversion: the MPEG/RVS reader). y (h, w); cb, cr (ceil(h/2), ceil(w/2)) or null (4:0:0);
// samples of `bits` bits as uint8 (bits <= 8) or uint16. Chroma is upsampled by the centred linear
// filter (3/4, 1/4; rows, then columns; clamped at the border), normalised (limited range: Y 16..235,
// C 16..240 scaled to the bit depth; full: 0..2^bits - 1), converted by the matrix (kr, kb), clipped
// to [0, 1] and decoded by SrgbToLinear. Every step in float32 with the same operations in the same
// order as the numpy definition (its constants rounded from double once), so the same bits.
// out (h, w, 3) float32; multithreaded over rows (each row independent).
// Throws BadValueError unless bits is in min_bits..16 and (kr, kb) a Y'CbCr matrix's weights
// (positive, kr + kb < 1, finite).
void YuvCheckArgs(int bits, double kr, double kb, int min_bits = 1);
template <class T>
void YuvToLinearRgb(const T* y, const T* cb, const T* cr, int h, int w, int bits, double kr, double kb,
                    bool full_range, float* out);

// Linear RGB -> Y'CbCr 4:2:0 planes (Python: ibrtools.formats.yuv.rgb_to_yuv, the inverse of
// YuvToLinearRgb, which defines it): rgb (h, w, 3) float32 encoded by LinearToSrgb's curve (clipped
// to [0, 1], NaN 0), then in double: the matrix (kr, kb), chroma averaged over each 2 x 2 block (the
// last row / column repeated for odd sizes), scaled to the code range (limited or full), rounded to
// nearest even and clipped to [0, 2^bits - 1]. The same double operations in the same order as the
// numpy definition, so the same codes. y (h, w), cb and cr (ceil(h/2), ceil(w/2)) of uint8 (bits 8)
// or uint16 (9..16 bits); multithreaded over chroma rows.
template <class T>
void LinearRgbToYuv(const float* rgb, int h, int w, int bits, double kr, double kb, bool full_range, T* y, T* cb,
                    T* cr);

// out[i] = table[codes[i]] for n stored 8- or 16-bit samples (table: 2^8 or 2^16 floats, the value of
// every code; Python: ibrtools.imageio.read_image's sRGB decode), multithreaded. The codes are read as
// they are (no widened index array: numpy's take of a uint8 (1080, 1920, 3) image first builds 50 MB of
// int64 indices).
void LookupCodes(const std::uint8_t* codes, const float* table, float* out, std::int64_t n);
void LookupCodes(const std::uint16_t* codes, const float* table, float* out, std::int64_t n);

// The linear value of every 8-bit sRGB code c = 0..255: SrgbToLinear of float(c) / 255 (a table of
// 256 values made once; exact 0 at 0 and 1 at 255 within SrgbToLinear's 1e-5).
const float* Srgb8ToLinearTable();

}  // namespace ibr
