"""DIBR: depth-image-based rendering with view selection (Bonatto et al. 2020).

``method`` is the ``dibr`` method (triangle warp of the selected inputs, quality-weighted
blend; the C++ kernels of ``cpp/kernels/dibr/``), ``warp`` the single-input ``warp`` method,
``view_selection`` the choice of inputs for a target camera (docs/dibr.md, docs/warp.md).
"""
