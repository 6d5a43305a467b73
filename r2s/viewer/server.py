"""Build the viser scene of a scene directory and serve it.

Scene tree (world frame, metres, Z up)::

    /observed/points            back-projected RGB-D, in the pixels' colours
    /observed/camera            the input camera's frustum
    /support                    a grid on the support plane
    /objects/<id>               frame at the object's pose (moved by the rollout player)
    /objects/<id>/visual        the textured visual mesh of export/
    /objects/<id>/collision/<k> convex collision pieces (hidden until toggled)
    /objects/<id>/moved         a red shell on objects that moved in the rollout
    /objects/<id>/label         "<id> <label>" (and the motion, if it moved)
    /graph/support, /graph/proximity   contact-graph edges between object centres

Controls: one checkbox per layer, and a rollout player (time slider, play, loop).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import trimesh
import viser
import viser.transforms as vtf

from r2s.geometry.overlay import UNMASKED_COLOR
from r2s.sim.render import colour_of
from r2s.viewer.playback import PLAYBACK_HZ, Playback, simulate_playback
from r2s.viewer.scene_data import (PROXIMITY_EDGE_RGB, SUPPORT_EDGE_RGB, ViewerScene,
                                   load_viewer_scene)

MOVED_RGB = (230, 30, 30)
"""Colour of the shell drawn over objects that moved in the rollout."""


def _rgb255(obj_id: int) -> tuple[int, int, int]:
    r, g, b, _ = colour_of(obj_id)
    return int(255 * r), int(255 * g), int(255 * b)


def _wxyz(rotation: np.ndarray) -> np.ndarray:
    return vtf.SO3.from_matrix(np.asarray(rotation, dtype=np.float64)).wxyz


def _plane_wxyz(normal: np.ndarray) -> np.ndarray:
    """Rotation taking +Z onto ``normal`` (for the support grid)."""
    z = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return _wxyz(np.stack([x, np.cross(z, x), z], axis=1))


@dataclass
class ViewerControls:
    """Handles of the layers and the player (tests and scripts drive them)."""

    layers: dict[str, Any] = field(default_factory=dict)        # checkbox per layer name
    nodes: dict[str, list[Any]] = field(default_factory=dict)   # scene handles per layer
    objects: dict[int, Any] = field(default_factory=dict)       # id -> frame handle
    time_slider: Any = None
    play: Any = None
    loop: Any = None

    def show_frame(self, playback: Playback, frame: int) -> None:
        """Put every object at its pose of ``frame``."""
        for k, obj_id in enumerate(playback.ids):
            handle = self.objects.get(int(obj_id))
            if handle is None:
                continue
            pose = playback.world_from_object[frame, k]
            handle.position = pose[:3, 3]
            handle.wxyz = _wxyz(pose[:3, :3])


def _add_layer_toggle(server: viser.ViserServer, controls: ViewerControls, name: str,
                      label: str, initial: bool) -> None:
    box = server.gui.add_checkbox(label, initial_value=initial)
    controls.layers[name] = box

    @box.on_update
    def _(_: Any) -> None:
        for handle in controls.nodes.get(name, []):
            handle.visible = box.value


def _add_observed(server: viser.ViserServer, scene: ViewerScene, controls: ViewerControls) -> None:
    if scene.points_m is None:
        return
    nodes = [server.scene.add_point_cloud("/observed/points", scene.points_m.astype(np.float32),
                                          scene.points_rgb, point_size=1.5 * scene.point_size_m,
                                          point_shape="circle", precision="float32")]
    cam = scene.camera
    if cam is not None:
        fov_y = 2.0 * np.arctan2(cam.height / 2.0, cam.K[1, 1])
        # viser's frustum looks along +Z with +Y down in the image, as OpenCV does
        nodes.append(server.scene.add_camera_frustum(
            "/observed/camera", fov=float(fov_y), aspect=cam.width / cam.height, scale=0.03,
            thickness=0.002, color=(60, 60, 60), wxyz=_wxyz(cam.world_from_camera[:3, :3]),
            position=cam.world_from_camera[:3, 3]))
    controls.nodes["observed"] = nodes


def _shell(mesh: trimesh.Trimesh, grow_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices pushed ``grow_m`` out along their normals, and faces (a highlight shell)."""
    geom = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
    geom.merge_vertices()
    verts = geom.vertices + grow_m * geom.vertex_normals
    return verts.astype(np.float32), np.asarray(geom.faces, dtype=np.uint32)


def _add_objects(server: viser.ViserServer, scene: ViewerScene, playback: Playback,
                 controls: ViewerControls) -> None:
    motion = {m.id: m for m in playback.motions}
    for name in ("reconstruction", "collision", "moved", "labels"):
        controls.nodes[name] = []
    for obj in scene.objects:
        base = f"/objects/{obj.id}"
        pose = obj.world_from_object
        controls.objects[obj.id] = server.scene.add_frame(
            base, show_axes=False, wxyz=_wxyz(pose[:3, :3]), position=pose[:3, 3])
        controls.nodes["reconstruction"].append(
            server.scene.add_mesh_trimesh(f"{base}/visual", obj.visual))
        for k, piece in enumerate(obj.collision):
            controls.nodes["collision"].append(server.scene.add_mesh_simple(
                f"{base}/collision/{k}", np.asarray(piece.vertices, dtype=np.float32),
                np.asarray(piece.faces, dtype=np.uint32), color=_rgb255(obj.id + k),
                opacity=0.7, flat_shading=True, visible=False))
        com_obj = np.linalg.inv(pose)[:3, :3] @ obj.com_world_m + np.linalg.inv(pose)[:3, 3]
        m = motion.get(obj.id)
        text = obj.name
        if m is not None and m.moved:
            verts, faces = _shell(obj.visual, 0.002)
            controls.nodes["moved"].append(server.scene.add_mesh_simple(
                f"{base}/moved", verts, faces, color=MOVED_RGB, opacity=0.45))
            text = f"{m.caption} (moved)"
        controls.nodes["labels"].append(server.scene.add_label(
            f"{base}/label", text, position=com_obj, font_screen_scale=0.8))


def _add_graph(server: viser.ViserServer, scene: ViewerScene, controls: ViewerControls) -> None:
    if scene.graph is None or len(scene.graph.kinds) == 0:
        return
    nodes = []
    kinds = np.asarray(scene.graph.kinds)
    for kind, rgb in (("support", SUPPORT_EDGE_RGB), ("proximity", PROXIMITY_EDGE_RGB)):
        sel = kinds == kind
        if sel.any():
            nodes.append(server.scene.add_line_segments(
                f"/graph/{kind}", scene.graph.points[sel].astype(np.float32), rgb,
                thickness=3.0, thickness_units="screen"))
    controls.nodes["graph"] = nodes


def _add_unmodelled(server: viser.ViserServer, scene: ViewerScene,
                    controls: ViewerControls) -> None:
    """The boxes of export/unmodelled.json: unmasked things the twin leaves out."""
    controls.nodes["unmodelled"] = [
        server.scene.add_box(f"/unmodelled/{k}", color=tuple(int(v) for v in UNMASKED_COLOR),
                             dimensions=tuple(float(v) for v in size), opacity=0.45,
                             wxyz=_wxyz(pose[:3, :3]), position=pose[:3, 3])
        for k, (pose, size) in enumerate(scene.unmodelled)]


def _add_support(server: viser.ViserServer, scene: ViewerScene) -> None:
    n = np.asarray(scene.export.support.normal, dtype=np.float64)
    n /= np.linalg.norm(n)
    c = scene.centre_m()
    p0 = np.asarray(scene.export.support.point, dtype=np.float64)
    foot = c - np.dot(c - p0, n) * n
    server.scene.add_grid("/support", width=0.6, height=0.6, cell_size=0.05, section_size=0.1,
                          plane_opacity=0.25, plane_color=(225, 225, 220),
                          wxyz=_plane_wxyz(n), position=foot - 0.0005 * n)


def _moved_markdown(playback: Playback) -> str:
    moved = [m for m in playback.motions if m.moved]
    if not moved:
        return (f"No object moved (every COM < 5 mm and turn < 2 deg over "
                f"{playback.times_s[-1]:.1f} s).")
    lines = [f"**Moved in {playback.times_s[-1]:.1f} s** (red):"]
    lines += [f"- {m.caption}" for m in sorted(moved, key=lambda m: -m.displacement_mm)]
    return "\n".join(lines)


def _add_player(server: viser.ViserServer, playback: Playback, controls: ViewerControls
                ) -> threading.Event:
    """Slider, play and loop controls; returns the event that stops the play thread."""
    duration = float(playback.times_s[-1])
    with server.gui.add_folder("Rollout (judge, PyBullet)"):
        controls.time_slider = server.gui.add_slider(
            "time [s]", min=0.0, max=duration, step=1.0 / PLAYBACK_HZ, initial_value=0.0)
        controls.play = server.gui.add_checkbox("play", initial_value=False)
        controls.loop = server.gui.add_checkbox("loop", initial_value=True)
        server.gui.add_markdown(_moved_markdown(playback))

    @controls.time_slider.on_update
    def _(_: Any) -> None:
        controls.show_frame(playback, playback.frame_at(float(controls.time_slider.value)))

    stop = threading.Event()

    def run() -> None:
        while not stop.wait(1.0 / PLAYBACK_HZ):
            if not controls.play.value:
                continue
            t = float(controls.time_slider.value) + 1.0 / PLAYBACK_HZ
            if t > duration + 1e-9:
                if not controls.loop.value:
                    controls.play.value = False
                    continue
                t = 0.0
            controls.time_slider.value = min(t, duration)

    threading.Thread(target=run, name="r2s-view-player", daemon=True).start()
    return stop


def build_viewer(server: viser.ViserServer, scene: ViewerScene, playback: Playback
                 ) -> tuple[ViewerControls, threading.Event]:
    """Add the scene's nodes and controls to ``server``; (controls, player stop event)."""
    server.scene.set_up_direction("+z")
    controls = ViewerControls()
    _add_support(server, scene)
    _add_observed(server, scene, controls)
    _add_objects(server, scene, playback, controls)
    _add_graph(server, scene, controls)
    _add_unmodelled(server, scene, controls)
    with server.gui.add_folder("Layers"):
        _add_layer_toggle(server, controls, "observed", "observed points", True)
        _add_layer_toggle(server, controls, "reconstruction", "reconstruction", True)
        _add_layer_toggle(server, controls, "collision", "collision pieces", False)
        _add_layer_toggle(server, controls, "graph", "contact graph", True)
        _add_layer_toggle(server, controls, "moved", "highlight moved", True)
        _add_layer_toggle(server, controls, "labels", "labels", True)
        if scene.unmodelled:
            _add_layer_toggle(server, controls, "unmodelled", "unmasked things (left out)",
                              True)
        server.gui.add_markdown(
            f"graph: <span style='color:rgb{SUPPORT_EDGE_RGB}'>support</span>, "
            f"<span style='color:rgb{PROXIMITY_EDGE_RGB}'>proximity</span>")
    stop = _add_player(server, playback, controls)
    for note in scene.notes:
        server.gui.add_markdown(f"_{note}_")
    c = scene.centre_m()
    if scene.camera is not None:
        # behind and above the input camera: the whole table in view, the camera's
        # frustum below the objects rather than in front of them
        eye = scene.camera.world_from_camera[:3, 3]
        back = 1.3 * (eye - c)
        server.initial_camera.position = c + back + np.array([0, 0, 0.5 * np.linalg.norm(back)])
    else:
        server.initial_camera.position = c + np.array([0.5, -0.5, 0.5])
    server.initial_camera.look_at = c
    server.initial_camera.up = (0.0, 0.0, 1.0)
    return controls, stop


@dataclass
class ViewerApp:
    """A running viewer: the viser server, what it shows, and its controls."""

    server: viser.ViserServer
    scene: ViewerScene
    playback: Playback
    controls: ViewerControls
    _stop_player: threading.Event

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    def stop(self) -> None:
        self._stop_player.set()
        self.server.stop()


def start_viewer(scene_dir: Path, host: str = "127.0.0.1", port: int = 8080,
                 progress: Callable[[str], None] = lambda _m: None) -> ViewerApp:
    """Read the scene, re-run the judge's rollout, start the server (returns at once)."""
    progress("reading the scene")
    scene = load_viewer_scene(Path(scene_dir))
    progress(f"re-simulating the rollout ({scene.rollout_duration_s:.1f} s)")
    playback = simulate_playback(scene.root / "export", scene.rollout_duration_s,
                                 scene.rollout_rate_hz)
    server = viser.ViserServer(host=host, port=port, verbose=False)
    controls, stop = build_viewer(server, scene, playback)
    return ViewerApp(server, scene, playback, controls, stop)


def serve_forever(app: ViewerApp) -> None:
    """Block until interrupted (Ctrl-C), then stop the server."""
    try:
        while True:
            time.sleep(1.0)
    finally:
        app.stop()
