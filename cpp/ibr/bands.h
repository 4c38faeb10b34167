// Binning of items (triangles, tiles) by the bands of image rows they cover, for rasterisers that
// give each band of rows to one task.
#pragma once

#include <cstdint>
#include <vector>

namespace ibr {

// A counting sort of items into bands of `band_rows` rows: afterwards band b's items are
// items[start[b] .. start[b + 1]), in the order for_each gave them. `for_each(emit)` must call
// emit(item, r0, r1) for every item covering rows [r0, r1] (0 <= r0 <= r1 < num_bands * band_rows),
// the same items in the same order each time (it is called twice: count, then fill).
template <class Item, class ForEach>
void BinByBand(int num_bands, int band_rows, ForEach&& for_each, std::vector<std::int64_t>& start,
               std::vector<Item>& items) {
  start.assign(static_cast<std::size_t>(num_bands) + 1, 0);
  for_each([&](const Item&, int r0, int r1) {
    for (int b = r0 / band_rows; b <= r1 / band_rows; ++b) ++start[static_cast<std::size_t>(b) + 1];
  });
  for (int b = 0; b < num_bands; ++b) start[static_cast<std::size_t>(b) + 1] += start[static_cast<std::size_t>(b)];
  items.resize(static_cast<std::size_t>(start.back()));
  std::vector<std::int64_t> next(start.begin(), start.end() - 1);
  for_each([&](const Item& item, int r0, int r1) {
    for (int b = r0 / band_rows; b <= r1 / band_rows; ++b) items[static_cast<std::size_t>(next[static_cast<std::size_t>(b)]++)] = item;
  });
}

}  // namespace ibr
