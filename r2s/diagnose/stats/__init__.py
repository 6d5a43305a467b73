"""Statistics of diagnose: residual blocks, BIC ranking, the noise-only evidence bar, the
test of a residual for structure, and the accept / revert rule of one loop step. Pure
functions of :mod:`r2s.diagnose.data` containers (no files, no stages)."""
