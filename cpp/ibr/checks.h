// Value scans for the input checks of the kernel fronts and the bindings: they find the first or
// count the bad values of an array and never throw (the caller words the error, naming the argument).
// Run on the calling thread; callers release the GIL around them for image-sized arrays.
#pragma once
#include <cmath>
#include <cstdint>

namespace ibr {

// The number of NaN and infinite values among v[0, n).
template <class T>
std::int64_t CountNonFiniteValues(const T* v, std::int64_t n) {
  std::int64_t bad = 0;
  for (std::int64_t i = 0; i < n; ++i) bad += !std::isfinite(v[i]);
  return bad;
}

// The first i in [0, n) with v[i] NaN or infinite, else -1.
template <class T>
std::int64_t FindNonFinite(const T* v, std::int64_t n) {
  for (std::int64_t i = 0; i < n; ++i) {
    if (!std::isfinite(v[i])) return i;
  }
  return -1;
}

// The first i in [0, n) with v[i] outside [lo, hi), else -1.
template <class T>
std::int64_t FindOutOfRange(const T* v, std::int64_t n, std::int64_t lo, std::int64_t hi) {
  for (std::int64_t i = 0; i < n; ++i) {
    if (v[i] < lo || v[i] >= hi) return i;
  }
  return -1;
}

// The first i in [0, n - 1) with v[i + 1] < v[i], else -1.
template <class T>
std::int64_t FindDecreasing(const T* v, std::int64_t n) {
  for (std::int64_t i = 0; i + 1 < n; ++i) {
    if (v[i + 1] < v[i]) return i;
  }
  return -1;
}

}  // namespace ibr
