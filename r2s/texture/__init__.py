"""Textures of object meshes: UV atlases, baking colours into texels, photometric refinement.

``uv`` makes a UV atlas for a mesh without one, ``bake`` rasterises a mesh in UV space and
fills texels from vertex colours, ``textured`` converts between trimesh meshes and the
arrays the optimiser works on, ``refine`` optimises textures against the observed image,
``scene`` ties them to one camera view (G-buffer, observed pixels, renders).
"""
