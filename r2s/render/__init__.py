"""Rendering of a scene whose geometry is fixed: a ray-cast G-buffer, then shading lookups.

``gbuffer`` casts one ray per pixel (Open3D) and records which object, which face and
where on that face each pixel sees; ``shade`` turns a G-buffer plus per-object colours
(texture or vertex colours) into an RGB image. Nothing here is differentiable: the torch
texture lookup lives in :mod:`r2s.texture.sampling`.
"""
