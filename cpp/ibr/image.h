// Non-owning views of images stored (row, col, channel), C-contiguous per row.
// Kernels take these and never allocate or check: the front (bindings) has already checked
// shapes and dtypes and allocated the outputs.
#pragma once
#include <cstddef>
#include <cstdint>

namespace ibr {

template <typename T>
struct ImageView {
  T* data = nullptr;
  int height = 0;
  int width = 0;
  int channels = 1;
  std::ptrdiff_t row_stride = 0;  // in elements; width * channels for a contiguous image

  ImageView() = default;
  ImageView(T* d, int h, int w, int c = 1)
      : data(d), height(h), width(w), channels(c), row_stride(std::ptrdiff_t(w) * c) {}

  T* Row(int y) const { return data + std::ptrdiff_t(y) * row_stride; }
  T& At(int y, int x, int c = 0) const { return Row(y)[std::ptrdiff_t(x) * channels + c]; }
  std::int64_t NumPixels() const { return std::int64_t(height) * width; }
  bool Empty() const { return data == nullptr || height <= 0 || width <= 0; }
};

}  // namespace ibr
