"""Iterative depth warping (Lee et al. 2023): backward warping by fixed-point iteration over an
N-buffer of the source depth, with conservative culling and shadows.

``core`` wraps the C++ warper and the N-buffer, ``culling`` the occlusion culling of the
sources, ``shadows`` the shadow maps, ``method`` the ``depthwarp`` method (docs/depthwarp.md).
"""
