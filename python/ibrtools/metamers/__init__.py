"""Ventral metamers (Walton et al. 2022): the steerable pyramid (``steerable``) and foveated
rendering by metamerisation (``foveate``); docs/foveate.md, docs/steerable.md.
"""
