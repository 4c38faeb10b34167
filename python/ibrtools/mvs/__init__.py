"""Multi-view stereo: per-view depth, normal and confidence from photographs and cameras alone
(PatchMatch stereo, the C++ kernels of ``cpp/kernels/mvs/``; docs/mvs.md).

``stereo`` holds the options (:class:`MvsOptions`), the source-view selection, the depth range,
the passes (photometric, geometric) and the filter; :func:`run_mvs` runs them over a scene's
views. The ``mvs`` stage of :mod:`ibrtools.pipeline.stages` calls it for the views without depth.
"""
from ibrtools.mvs.stereo import MvsOptions, MvsResult, depth_range, grey, run_mvs, select_sources

__all__ = ["MvsOptions", "MvsResult", "depth_range", "grey", "run_mvs", "select_sources"]
