"""Hybrid image-based rendering preprocessing (Prakash et al. 2021, sec. 4 and 5.1).

Modules: ``globalmesh`` (the global mesh: the scene's reconstructed mesh or TSDF fusion of the
views' depth maps, per-vertex colour by ULR-weighted blending, per-view depth from the mesh),
``pvm`` (per-view meshes sliced into a two-level voxel grid of tiles), ``variance`` and
``harmonise`` (photometric variance and multi-view harmonisation). The stage planner
(``ibrtools.pipeline.stages``) runs them and caches their outputs under ``SCENE/cache/<stage>/``.
"""
