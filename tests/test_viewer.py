"""``r2s view``: the data it shows, the rollout player, and the page in headless Chromium."""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np
import pytest

from tests.helpers_viewer import BOX_RGB, DROP_M, checker_rgb, write_viewer_scene

viser = pytest.importorskip("viser", reason="the viewer needs viser (pip install '.[view]')")

from r2s.errors import R2SError  # noqa: E402
from r2s.viewer.browser import distinct_colours, find_chromium, screenshot  # noqa: E402
from r2s.viewer.playback import simulate_playback  # noqa: E402
from r2s.viewer.scene_data import load_viewer_scene  # noqa: E402
from r2s.viewer.server import start_viewer  # noqa: E402


@pytest.fixture(scope="module")
def viewer_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_viewer_scene(tmp_path_factory.mktemp("viewer") / "scene")


def test_observed_points_lie_on_the_plane_with_their_colours(viewer_scene: Path) -> None:
    scene = load_viewer_scene(viewer_scene)
    assert scene.points_m is not None and len(scene.points_m) > 1000
    # the depth is the plane z = 0: every back-projected point is on it (float32 depth)
    assert np.abs(scene.points_m[:, 2]).max() < 1e-5
    # and carries the checkerboard colour of where it lands (skip points on square edges)
    xy = scene.points_m[:, :2]
    frac = np.abs(xy / 0.05 - np.round(xy / 0.05))
    inside = (frac > 0.02).all(axis=1)
    assert inside.sum() > 0.8 * len(xy)
    np.testing.assert_array_equal(scene.points_rgb[inside], checker_rgb(xy[inside]))
    assert scene.notes == []


def test_graph_segments_join_object_centres(viewer_scene: Path) -> None:
    scene = load_viewer_scene(viewer_scene)
    centre = {o.id: o.com_world_m for o in scene.objects}
    np.testing.assert_allclose(centre[1], [-0.05, 0.0, 0.03], atol=1e-12)
    segs = {(kind, pair): pts for kind, pair, pts in
            zip(scene.graph.kinds, scene.graph.pairs, scene.graph.points)}
    assert set(segs) == {("support", (1, 0)), ("support", (2, 0)), ("support", (3, 0)),
                         ("proximity", (1, 2))}
    # a support edge to the table ends at the child's centre dropped onto the plane z = 0
    np.testing.assert_allclose(segs[("support", (2, 0))], [[0.05, 0, 0.04], [0.05, 0, 0.0]],
                               atol=1e-12)
    np.testing.assert_allclose(segs[("proximity", (1, 2))], [centre[1], centre[2]], atol=1e-12)
    colours = scene.graph.colours()
    assert colours.shape == (4, 2, 3)
    assert len({tuple(c[0]) for c in colours}) == 2          # one colour per kind


def test_playback_finds_the_falling_box(viewer_scene: Path) -> None:
    scene = load_viewer_scene(viewer_scene)
    assert scene.rollout_duration_s == 1.0
    play = simulate_playback(viewer_scene / "export", scene.rollout_duration_s,
                             scene.rollout_rate_hz)
    assert play.times_s[-1] == pytest.approx(1.0, abs=1e-9)
    assert np.diff(play.times_s).max() == pytest.approx(1 / 30, abs=1 / 240 + 1e-9)
    motion = {m.id: m for m in play.motions}
    assert play.moved_ids == [3]
    # box 3 falls DROP_M onto the plane (PyBullet's contact margin leaves < 1.5 mm)
    assert motion[3].displacement_mm == pytest.approx(1000 * DROP_M, abs=1.5)
    assert motion[1].displacement_mm < 1.0 and motion[2].displacement_mm < 1.0
    assert play.frame_at(0.0) == 0 and play.frame_at(10.0) == len(play.times_s) - 1


def test_missing_export_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(R2SError, match="export/scene.json: missing"):
        load_viewer_scene(tmp_path)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.slow
def test_viewer_page_in_headless_chromium(viewer_scene: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture) -> None:
    if find_chromium() is None:
        pytest.skip("no Chromium on PATH (scripts/setup_env.sh installs Debian's 'chromium')")
    app = start_viewer(viewer_scene, host="127.0.0.1", port=_free_port())
    try:
        api = app.server.scene
        for name in ("/observed/points", "/observed/camera", "/support", "/graph/support",
                     "/graph/proximity", "/objects/1/visual", "/objects/2/visual",
                     "/objects/3/visual", "/objects/3/moved", "/objects/1/collision/0"):
            assert api.get_handle_by_name(name) is not None, name
        assert api.get_handle_by_name("/objects/1/moved") is None     # box 1 did not move
        piece = api.get_handle_by_name("/objects/1/collision/0")
        assert piece.visible is False
        app.controls.layers["collision"].value = True
        assert piece.visible is True
        app.controls.layers["collision"].value = False
        # the player puts box 3 where the rollout left it
        frame3 = api.get_handle_by_name("/objects/3")
        z0 = float(frame3.position[2])
        app.controls.time_slider.value = app.controls.time_slider.max
        k = list(app.playback.ids).index(3)
        np.testing.assert_allclose(frame3.position, app.playback.world_from_object[-1, k, :3, 3],
                                   atol=1e-6)
        assert z0 - float(frame3.position[2]) == pytest.approx(DROP_M, abs=1.5e-3)
        app.controls.time_slider.value = 0.0

        shot_path = tmp_path / "viewer_screenshot.png"
        image = screenshot(app.url, shot_path, timeout_s=150.0)
        with capsys.disabled():                    # shown in the test output, even when passing
            print(f"\nviewer screenshot: {shot_path}")
    finally:
        app.stop()
    assert shot_path.is_file()
    assert app.server.get_port() > 0
    assert distinct_colours(image) > 500
    # the 3D canvas left of the control panel is not blank: the table, points and boxes
    canvas = image[:, : int(0.6 * image.shape[1])].astype(int)
    non_white = (np.abs(canvas - 255).max(axis=-1) > 30).mean()
    assert non_white > 0.1, non_white
    # the blue box and the red shell of the box that moved are both on screen
    r, g, b = canvas[..., 0], canvas[..., 1], canvas[..., 2]
    blue = (b > 140) & (r < 110) & (g < 130) & (b - r > 60)
    red = (r > 150) & (g < 110) & (b < 110) & (r - g > 60)
    assert blue.sum() > 30, blue.sum()
    assert red.sum() > 30, red.sum()
    assert BOX_RGB[1][2] > BOX_RGB[1][0]      # (the test's colour assumption)


def test_view_command_without_export_is_one_line(tmp_path: Path) -> None:
    import subprocess
    import sys

    from tests.conftest import REPO

    proc = subprocess.run([sys.executable, "-m", "r2s.cli", "view", str(tmp_path)],
                          capture_output=True, text=True, cwd=REPO, timeout=120,
                          env={**__import__("os").environ, "PYTHONPATH": str(REPO)})
    assert proc.returncode == 2
    assert "export/scene.json: missing" in proc.stdout + proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr


def test_player_plays_to_the_end_and_stops_without_loop(viewer_scene: Path) -> None:
    import time

    app = start_viewer(viewer_scene, host="127.0.0.1", port=_free_port())
    try:
        c = app.controls
        c.loop.value = False
        c.play.value = True
        deadline = time.monotonic() + 30.0
        while c.play.value and time.monotonic() < deadline:
            time.sleep(0.05)
        assert c.play.value is False                      # it stopped by itself at the end
        assert float(c.time_slider.value) == pytest.approx(c.time_slider.max, abs=1e-9)
        k = list(app.playback.ids).index(3)
        frame3 = app.server.scene.get_handle_by_name("/objects/3")
        np.testing.assert_allclose(frame3.position, app.playback.world_from_object[-1, k, :3, 3],
                                   atol=1e-6)
    finally:
        app.stop()


def test_unmasked_things_are_boxes_in_their_own_layer(tmp_path: Path) -> None:
    from r2s.io.unmodelled import write_unmodelled

    scene_dir = write_viewer_scene(tmp_path / "scene")
    assert load_viewer_scene(scene_dir).unmodelled == []
    pose = np.eye(4)
    pose[:3, 3] = [0.1, -0.05, 0.025]
    write_unmodelled(scene_dir / "export", [{"world_from_box": pose.tolist(),
                                             "size_m": [0.08, 0.06, 0.05], "height_m": 0.05}])
    ((got_pose, got_size),) = load_viewer_scene(scene_dir).unmodelled
    np.testing.assert_allclose(got_pose, pose)
    np.testing.assert_allclose(got_size, [0.08, 0.06, 0.05])
    app = start_viewer(scene_dir, host="127.0.0.1", port=_free_port())
    try:
        (box,) = app.controls.nodes["unmodelled"]
        np.testing.assert_allclose(box.position, [0.1, -0.05, 0.025], atol=1e-6)
        toggle = app.controls.layers["unmodelled"]
        toggle.value = False
        assert box.visible is False
    finally:
        app.stop()
