"""Simulators: PyBullet helpers (the judge's engine) and r2s's differentiable torch simulator."""
