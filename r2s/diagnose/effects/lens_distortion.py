"""Effect ``lens_distortion``: the RGB-D camera's lens bends rays radially (Brown's k1, k2).

camera.json gives an ideal pinhole ``K``; a real lens records the point seen along the
ideal ray ``x`` at ``x (1 + k1 r^2 + k2 r^4)`` (:mod:`r2s.geometry.lens`). Depth values are
right, but they land at the wrong pixels, so the back-projected table is no longer a
plane: a bowl or a dome about the principal point whose depth grows with the radius. The
fit finds the ``k1`` whose undistortion makes the table points flattest (the
``table_shape`` block); ``k2`` is held at 0: the table seen in one image rarely reaches
radii where the two separate (``k2`` is kept in the parameters and applied when given).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import minimize_scalar

from r2s.diagnose.stats.blocks import table_shape_block
from r2s.diagnose.data import Residuals, SupportData, TableShapeData
from r2s.diagnose.effects._depth_model import support_refitted
from r2s.diagnose.effects.base import Effect, EffectFit, make_fit, not_identifiable
from r2s.geometry.lens import undistort_image, undistort_normalised
from r2s.io.input_scene import InputScene

K1_BOUND = 0.4


def undistort_points(points_camera: np.ndarray, k1: float, k2: float = 0.0) -> np.ndarray:
    """(N, 3) camera-frame points back-projected through the undistorted pixel rays (the
    camera-z depth of each point is kept)."""
    p = np.asarray(points_camera, dtype=np.float64)
    z = p[:, 2:3]
    x = undistort_normalised(p[:, :2] / z, k1, k2)
    return np.hstack([x * z, z])


def undistorted_shape(data: TableShapeData, k1: float, k2: float = 0.0) -> TableShapeData:
    return replace(data, points_camera=undistort_points(data.points_camera, k1, k2))


def undistorted_support(sup: SupportData, k1: float, k2: float = 0.0) -> SupportData:
    """The support plane refitted on its inliers moved onto the undistorted rays."""
    if sup.points_camera is None or sup.world_from_camera is None:
        return sup
    return support_refitted(sup, undistort_points(sup.points_camera, k1, k2))


class LensDistortion(Effect):
    name = "lens_distortion"
    n_params = 1
    level = "input"
    preference = 5
    signature = (
        "The table's back-projected points bend away from one plane in a pattern that is "
        "symmetric about the principal point (a bowl or a dome: the distance to the plane "
        "grows with the squared image radius), while the depths themselves are consistent. "
        "Fit: the radial coefficient k1 whose undistortion of the table pixels makes them "
        "flattest (k2 held at 0)."
    )

    def fit(self, residuals: Residuals) -> EffectFit:
        shape = residuals.table_shape
        if shape is None or len(shape.points_camera) < 100:
            return not_identifiable(self.name, residuals, "too few table pixels")

        def cost(k1: float) -> float:
            return table_shape_block(undistorted_shape(shape, k1)).sse

        sol = minimize_scalar(cost, bounds=(-K1_BOUND, K1_BOUND), method="bounded",
                              options={"xatol": 1e-4})
        k1 = float(sol.x)
        after = replace(residuals, table_shape=undistorted_shape(shape, k1))
        if residuals.support is not None:
            after = replace(after, support=undistorted_support(residuals.support, k1))
        params = {"k1": k1, "k2": 0.0}
        return make_fit(self.name, residuals, after, params, self.n_params, k1, "",
                        note=self.describe(params))

    def apply_to_input(self, scene: InputScene, params: dict) -> InputScene:
        k1, k2 = float(params.get("k1", 0.0)), float(params.get("k2", 0.0))
        K = scene.camera.K
        depth = undistort_image(scene.depth_m, K, k1, k2, nearest=True, fill=np.nan)
        masks = undistort_image(scene.masks, K, k1, k2, nearest=True, fill=0)
        rgb = undistort_image(scene.rgb, K, k1, k2, nearest=False, fill=0.0)
        return replace(scene, depth_m=depth.astype(np.float32),
                       masks=masks.astype(scene.masks.dtype),
                       rgb=np.clip(np.rint(rgb), 0, 255).astype(np.uint8))

    def compose(self, old: dict, new: dict) -> dict:
        # to first order in the coefficients, undistorting twice adds them
        return {"k1": float(old.get("k1", 0.0)) + float(new.get("k1", 0.0)),
                "k2": float(old.get("k2", 0.0)) + float(new.get("k2", 0.0))}

    def describe(self, params: dict) -> str:
        return (f"radial lens distortion k1 = {params.get('k1', 0.0):+.4f}, "
                f"k2 = {params.get('k2', 0.0):+.4f}")


EFFECT = LensDistortion()
