"""The Embree ray caster (``reference``): the ground-truth renderer of meshes, the depth of views
from a mesh, and the ``reference`` method (docs/reference.md).
"""
