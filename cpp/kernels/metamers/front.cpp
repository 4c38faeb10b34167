// The metamers family's front (front.h).
#include "kernels/metamers/front.h"

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "ibr/errors.h"
#include "kernels/metamers/mip.h"
#include "kernels/metamers/steerable.h"

namespace ibr {

void SteerableCheckOptions(int orientations, int levels, int h, int w) {
  if (!SteerableOrientationsSupported(orientations)) {
    throw BadValueError("orientations: expected 2 or 4 (the fitted taps in cpp/kernels/metamers/steerable_taps.h), got " +
                        std::to_string(orientations));
  }
  const int max_levels = SteerableMaxLevels(h, w);
  if (levels < 0 || levels > max_levels) {
    throw BadValueError("levels: expected 0.." + std::to_string(max_levels) + " for a " + std::to_string(h) + "x" +
                        std::to_string(w) + " image (every level's input must be at least 3x3), got " +
                        std::to_string(levels));
  }
}

void SteerableCheckFinite(const ImageView<const float>& image, const std::string& name) {
  if (const std::int64_t bad = SteerableCountNonFinite(image)) {
    throw BadValueError(name + ": contains " + std::to_string(bad) + " NaN or infinite values");
  }
}

void MipBuildChain(const ImageView<const float>& in, const ImageView<float>* views, int levels) {
  for (int l = 0; l < levels; ++l) {
    const ImageView<float>& prev = views[l > 0 ? l - 1 : 0];
    const ImageView<const float> src =
        l == 0 ? in : ImageView<const float>(prev.data, prev.height, prev.width, prev.channels);
    MipDown(src, views[l]);
  }
}

void MipFoveateLevel(const ImageView<float>* bands, int k, const ImageView<const float>& level,
                     const ImageView<const float>* noise, int levels) {
  const int h = bands[0].height, w = bands[0].width, c = bands[0].channels;
  std::vector<std::vector<float>> chain;
  std::vector<ImageView<float>> chain_views;
  std::vector<ImageView<const float>> band_in, chain_in;
  int lh = h, lw = w;
  for (int l = 0; l < levels; ++l) {
    lh = (lh + 1) / 2;
    lw = (lw + 1) / 2;
    chain.emplace_back(std::size_t(lh) * lw * 2 * k * c);
    chain_views.emplace_back(chain.back().data(), lh, lw, 2 * k * c);
    chain_in.emplace_back(chain.back().data(), lh, lw, 2 * k * c);
  }
  for (int i = 0; i < k; ++i) {
    band_in.emplace_back(bands[i].data, bands[i].height, bands[i].width, bands[i].channels);
    band_in.back().row_stride = bands[i].row_stride;
  }
  for (int l = 0; l < levels; ++l) {
    if (l == 0) {
      MipDownMoments(band_in.data(), k, chain_views[0]);
    } else {
      MipDown(chain_in[l - 1], chain_views[l]);
    }
  }
  MipFoveateChange(bands, k, chain_in.data(), levels, level, noise);
}

}  // namespace ibr
