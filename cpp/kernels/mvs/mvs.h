// The checked front of the multi-view stereo family: options' bounds and inputs' consistency
// are checked here (typed errors, ibr/errors.h), then the kernels of patchmatch.h run. Python:
// ibrtools.mvs (source selection, depth ranges, passes, filtering), the `mvs` stage.
#pragma once
#include <vector>

#include "kernels/mvs/patchmatch.h"

namespace ibr::mvs {

// Bounds of PatchMatchOptions (one place; ibrtools.mvs.MvsOptions states the same bounds).
constexpr int kMaxWindowRadius = 15;
constexpr int kMaxIterations = 64;
constexpr int kMaxSourceViews = 32;

// Throws BadValueError naming the option when it is out of its bounds.
void CheckOptions(const PatchMatchOptions& options);

// Checks the views (pinhole, at least 2 x 2 pixels, grey sizes equal to their cameras', depth maps
// (optional per source: the geometric term uses the sources that have one) of their sizes,
// 1..kMaxSourceViews sources, no source at the reference's centre) and the outputs' shapes, then
// runs PatchMatch.
PatchMatchStats RunPatchMatch(const ImageView<const float>& ref_grey, const Camera& ref_cam,
                              const std::vector<SourceView>& sources, const PatchMatchOptions& options,
                              bool initialised, ImageView<float> depth, ImageView<float> normal,
                              ImageView<float> cost);

// Checks as RunPatchMatch (every source with depth), then runs ConsistentViews.
void RunConsistentViews(const ImageView<const float>& ref_depth, const Camera& ref_cam,
                        const std::vector<SourceView>& sources, float max_error_px, float max_rel_depth,
                        float min_angle_deg, ImageView<float> count);

}  // namespace ibr::mvs
