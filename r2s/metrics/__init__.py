"""What the judge measures: stability of a rollout, interpenetration / floating before it,
and geometry against ground truth. Pure functions on arrays and meshes, except
:mod:`r2s.metrics.penetration`, which queries a PyBullet client."""
