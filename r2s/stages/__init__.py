"""Pipeline stages. Each stage module defines ``STAGE = StageSpec(...)``; see :mod:`r2s.runner.base`."""
