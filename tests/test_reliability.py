"""The reliability catalogue (docs/reliability.md): concurrent runs, kills, bad units,
degenerate inputs, non-finite numbers, paths with any characters, read-only scenes.

Every case must end in exit 0 with a correct scene, or one clear line (error, or warning
plus a flag in the stage summary) - never exit 0 with an unflagged wrong scene. The
end-to-end cases run the real ``r2s`` command line on a two-box scene (96 x 72 pixels)
whose path holds spaces, accents and CJK characters.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from pydantic import Field

from r2s.errors import InputError, StageError
from r2s.io.atomic import recover_scene
from r2s.io.input_scene import MIN_MASK_PIXELS, load_input
from r2s.io.output_check import file_hashes
from r2s.io.paths import ScenePaths
from r2s.io.scene_lock import LOCK_NAME, SceneBusyError, SceneNotWritableError, scene_lock
from r2s.io.state import SceneState, SupportPlane, ObjectState, write_state
from r2s.runner.base import StageContext, StageOptions, StageSpec, run_stage, staleness
from r2s.io.manifest import load_manifest

REPO = Path(__file__).resolve().parents[1]
UNICODE_DIR = "scène ü 桌面 test"
RUN_OPTIONS = ["--set", "evaluate.render=false", "--set", "texture.iterations=20"]
"""Minimal options: the catalogue is about the machinery, not the result's quality."""


# ---- scenes --------------------------------------------------------------------------------


def write_two_boxes(scene: Path, width: int = 96, height: int = 72,
                    depth_unit_m: float = 0.001, depth_scale: float = 1.0) -> Path:
    """A camera 0.5 m above a table looking down; boxes 1 (3 cm tall) and 2 (4 cm tall).

    depth.png holds millimetres times ``depth_scale``; camera.json says ``depth_unit_m``.
    """
    inp = scene / "input"
    inp.mkdir(parents=True)
    fx = 90.0
    K = [[fx, 0, (width - 1) / 2], [0, fx, (height - 1) / 2], [0, 0, 1]]
    world_from_camera = [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0.5], [0, 0, 0, 1]]
    (inp / "camera.json").write_text(json.dumps(
        {"width": width, "height": height, "K": K, "world_from_camera": world_from_camera,
         "depth_unit_m": depth_unit_m}))
    depth_mm = np.full((height, width), 500.0)
    masks = np.zeros((height, width), np.uint8)
    masks[20:44, 14:40] = 1
    depth_mm[masks == 1] = 470
    masks[24:50, 56:80] = 2
    depth_mm[masks == 2] = 460
    Image.fromarray(np.round(depth_mm * depth_scale).astype(np.uint16)).save(inp / "depth.png")
    Image.fromarray(masks).save(inp / "masks.png")
    rgb = np.full((height, width, 3), 200, np.uint8)
    rgb[masks == 1] = (200, 40, 40)
    rgb[masks == 2] = (40, 40, 200)
    Image.fromarray(rgb).save(inp / "rgb.png")
    return scene


def box1_size_m() -> np.ndarray:
    """Box 1's true size: 26 x 24 pixels at 0.47 m depth, fx 90; 3 cm tall."""
    return np.array([26 * 0.47 / 90, 24 * 0.47 / 90, 0.03])


def add_prior(scene: Path, mesh: trimesh.Trimesh, obj_id: int = 1) -> Path:
    priors = scene / "input" / "priors"
    priors.mkdir(exist_ok=True)
    path = priors / f"{obj_id}.obj"
    mesh.export(path)
    (scene / "input" / "objects.json").write_text(json.dumps(
        {"objects": [{"id": obj_id, "label": "box", "prior_mesh": f"priors/{obj_id}.obj"}]}))
    return path


def r2s(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "200"}
    return subprocess.run([sys.executable, "-m", "r2s.cli", *args], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=REPO)


def r2s_background(*args: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "200"}
    return subprocess.Popen([sys.executable, "-m", "r2s.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env, cwd=REPO)


def error_lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip().startswith("error")]


def stage_outputs(scene: Path) -> dict[str, str]:
    """sha256 of every file of every stage folder and export/ (manifest.json aside)."""
    out: dict[str, str] = {}
    for folder in ScenePaths(scene).root.iterdir():
        if folder.is_dir() and folder.name not in ("input", "gt", ".cache") \
                and not folder.name.startswith("."):
            out.update({f"{folder.name}/{k}": v for k, v in file_hashes(folder).items()})
    return out


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory) -> Path:
    """One full ``r2s run`` of the two-box scene under a path with spaces, accents, CJK."""
    scene = write_two_boxes(tmp_path_factory.mktemp("rel") / UNICODE_DIR / "scene")
    result = r2s("run", str(scene), *RUN_OPTIONS)
    assert result.returncode == 0, result.stdout + result.stderr
    return scene


def fresh_copy(src: Path, dst: Path, with_outputs: bool) -> Path:
    """A copy of the scene; keep the folder's name (graph.png's title shows it)."""
    assert dst.name == src.name
    if with_outputs:
        shutil.copytree(src, dst, ignore=shutil.ignore_patterns(LOCK_NAME))
    else:
        shutil.copytree(src / "input", dst / "input")
    return dst


# ---- the scene lock ------------------------------------------------------------------------

HOLD_LOCK = textwrap.dedent("""
    import sys, time
    from r2s.io.scene_lock import scene_lock
    with scene_lock(sys.argv[1], command="holder"):
        print("locked", flush=True)
        time.sleep(float(sys.argv[2]))
""")


def _hold_lock(scene: Path, seconds: float) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(scene), str(seconds)],
                            stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_second_writer_stops_with_one_line_naming_the_holder(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    holder = _hold_lock(scene, 60)
    try:
        result = r2s("init", str(scene))
    finally:
        holder.kill()
        holder.wait()
    assert result.returncode == SceneBusyError.exit_code
    lines = error_lines(result.stdout + result.stderr)
    assert len(lines) == 1 and f"pid {holder.pid}" in lines[0] and "holder" in lines[0]
    assert "Traceback" not in result.stdout + result.stderr
    assert not (scene / "init").exists()


SLOW_NAMING_HOLDER = textwrap.dedent("""
    import fcntl, json, os, socket, sys, time
    fd = os.open(os.path.join(sys.argv[1], ".r2s-lock"), os.O_RDWR | os.O_CREAT, 0o644)
    os.ftruncate(fd, 0)
    fcntl.flock(fd, fcntl.LOCK_EX)
    print("locked", flush=True)
    time.sleep(0.5)  # the lock is held, the file still empty
    os.pwrite(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                              "since": "now", "command": "slow"}).encode(), 0)
    time.sleep(60)
""")


def test_refused_writer_names_a_holder_that_writes_its_name_late(tmp_path: Path):
    """The holder takes the lock a moment before it writes the lock file (the race two
    ``r2s run`` started together hit): the refused process still names it."""
    scene = write_two_boxes(tmp_path / "scene")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    holder = subprocess.Popen([sys.executable, "-c", SLOW_NAMING_HOLDER, str(scene)],
                              stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(SceneBusyError, match=f"written by pid {holder.pid} .*slow"):
            with scene_lock(scene, wait_s=0):
                pass
    finally:
        holder.kill()
        holder.wait()


def test_waiting_writer_gets_the_lock_when_the_holder_ends(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    holder = _hold_lock(scene, 1.5)
    told: list[str] = []
    t0 = time.monotonic()
    with scene_lock(scene, wait_s=30, notify=told.append):
        waited_s = time.monotonic() - t0
    holder.wait()
    assert 0.5 < waited_s < 30
    assert len(told) == 1 and "waiting up to 30 s" in told[0] and f"pid {holder.pid}" in told[0]
    with pytest.raises(SceneBusyError, match="gave up after waiting 0.3 s"):
        holder = _hold_lock(scene, 30)
        try:
            with scene_lock(scene, wait_s=0.3):
                pass
        finally:
            holder.kill()
            holder.wait()


def test_lock_of_a_killed_process_is_taken_over(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    holder = _hold_lock(scene, 60)
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    told: list[str] = []
    with scene_lock(scene, wait_s=0, notify=told.append):
        info = json.loads((scene / LOCK_NAME).read_text())
    assert info["pid"] == os.getpid()
    assert len(told) == 1 and f"left by pid {holder.pid}" in told[0]


def test_lock_is_reentrant_within_a_process(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    with scene_lock(scene):
        with scene_lock(scene):  # run_pipeline holds it, run_stage takes it again
            pass
        holder_text = (scene / LOCK_NAME).read_text()
        assert json.loads(holder_text)["pid"] == os.getpid()
    assert (scene / LOCK_NAME).read_text() == ""  # released: nobody holds it


def test_read_only_scene_gets_one_line(tmp_path: Path, monkeypatch):
    scene = write_two_boxes(tmp_path / "scene")
    if os.geteuid() != 0:
        scene.chmod(0o555)
        try:
            result = r2s("run", str(scene))
        finally:
            scene.chmod(0o755)
        assert result.returncode == 2
        lines = error_lines(result.stdout + result.stderr)
        assert len(lines) == 1 and "not writable" in lines[0]
        assert "Traceback" not in result.stdout + result.stderr
        return
    # root writes anywhere: make the file system refuse as a read-only mount does
    import r2s.io.scene_lock as lock_module

    def refuse(path, *args, **kwargs):
        raise OSError(30, "Read-only file system", str(path))

    monkeypatch.setattr(lock_module.os, "open", refuse)
    from r2s.runner.pipeline import run_pipeline

    with pytest.raises(SceneNotWritableError, match="not writable .read-only file system."):
        run_pipeline(scene)
    assert sorted(p.name for p in scene.iterdir()) == ["input"]


# ---- a stage folder is whole or not done ----------------------------------------------------


class MeshOptions(StageOptions):
    write_mesh: bool = Field(True)


def _mesh_stage(ctx: StageContext) -> dict:
    (ctx.out_dir / "meshes").mkdir()
    if ctx.options.write_mesh:
        trimesh.creation.box([0.1, 0.1, 0.1]).export(ctx.out_dir / "meshes" / "1.glb")
    write_state(ctx.out_dir, SceneState(
        stage="meshy", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
        objects=[ObjectState(id=1, label="box", mesh="meshes/1.glb",
                             world_from_object=np.eye(4).tolist())]))
    return {}


MESHY = StageSpec("meshy", MeshOptions, lambda paths, o, m: [paths.input / "rgb.png"], _mesh_stage)


def test_stage_missing_a_declared_file_is_never_recorded_done(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    with pytest.raises(StageError, match=r"did not write meshes/1.glb"):
        run_stage(MESHY, scene, MeshOptions(write_mesh=False))
    assert load_manifest(scene / "manifest.json").stages.get("meshy") is None
    assert not (scene / "meshy").exists()
    assert not list(scene.glob(".tmp-*"))


def test_inconsistent_stage_folder_is_rerun(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    paths = ScenePaths(scene)
    run_stage(MESHY, scene, MeshOptions())
    good = (scene / "meshy" / "meshes" / "1.glb").read_bytes()
    rec = load_manifest(paths.manifest).stages["meshy"]
    assert set(rec.model_extra["output_files"]) == {"meshes/1.glb", "state.json"}

    (scene / "meshy" / "meshes" / "1.glb").unlink()  # what a second writer used to do
    reason = staleness(MESHY, paths, MeshOptions(), load_manifest(paths.manifest))
    assert reason == ("output inconsistent: meshes/1.glb missing (named in its JSON), "
                      "meshes/1.glb missing")
    assert run_stage(MESHY, scene, MeshOptions(), force=False).ran
    assert (scene / "meshy" / "meshes" / "1.glb").read_bytes() == good

    (scene / "meshy" / "meshes" / "1.glb").write_bytes(b"changed")
    reason = staleness(MESHY, paths, MeshOptions(), load_manifest(paths.manifest))
    assert reason == "output inconsistent: meshes/1.glb changed"
    assert run_stage(MESHY, scene, MeshOptions(), force=False).ran
    assert staleness(MESHY, paths, MeshOptions(), load_manifest(paths.manifest)) == ""


def test_stale_scratch_folders_are_removed_at_start(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    run_stage(MESHY, scene, MeshOptions())
    (scene / ".tmp-geomopt-999999").mkdir()
    (scene / ".tmp-export-1" / "meshes").mkdir(parents=True)
    os.replace(scene / "meshy", scene / ".old-meshy")  # a swap cut in half
    touched = recover_scene(scene)
    assert touched == [".old-meshy", ".tmp-export-1", ".tmp-geomopt-999999"]
    assert sorted(p.name for p in scene.iterdir() if p.name != "manifest.json") == \
        [".r2s-lock", "input", "meshy"]


# ---- sanity checks -------------------------------------------------------------------------


def _init(scene: Path, options: dict | None = None):
    from r2s.runner.pipeline import run_single_stage

    return run_single_stage(scene, "init", options or {})


def test_millimetre_prior_is_refused(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    prior = add_prior(scene, trimesh.creation.box(box1_size_m() * 1000))
    with pytest.raises(InputError) as err:
        _init(scene)
    message = str(err.value)
    assert message.startswith(f"{prior}: object 1: prior is ")
    ratio = float(message.split("prior is ")[1].split("x")[0])
    # prior diagonal / observed (top face, 2-98 % box) diagonal: about 1000 x
    assert 900 < ratio < 1300
    assert "millimetres" in message and not (scene / "init").exists()


@pytest.mark.slow  # the 5x prior sends ICP into its global search
def test_metre_prior_passes_and_a_5x_prior_is_flagged(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    add_prior(scene, trimesh.creation.box(box1_size_m()))
    flags = _init(scene).summary["flags"]
    assert flags == []
    shutil.rmtree(scene / "init")
    add_prior(scene, trimesh.creation.box(box1_size_m() * 5))
    flags = _init(scene).summary["flags"]
    assert any(f.startswith("object 1: prior is 5.") and "observed size" in f for f in flags)
    # by default the completion from the observation replaces a prior that does not fit
    assert any(f.startswith("object 1: its prior was replaced by the completion") for f in flags)
    assert not any(f.startswith("object 1: fit explains") for f in flags)
    shutil.rmtree(scene / "init")
    flags = _init(scene, {"prior_choice": "prior"}).summary["flags"]  # kept: flagged
    assert any(f.startswith("object 1: fit explains") for f in flags)


def test_three_face_prior_is_refused(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    box = trimesh.creation.box(box1_size_m())
    prior = add_prior(scene, trimesh.Trimesh(box.vertices, box.faces[:3], process=False))
    with pytest.raises(InputError, match=r"object 1: degenerate prior: 3 faces"):
        _init(scene)
    flat = trimesh.Trimesh([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0]],
                           [[0, 1, 2], [1, 3, 2], [0, 2, 1], [1, 2, 3]], process=False)
    prior.unlink()
    add_prior(scene, flat)
    with pytest.raises(InputError, match=r"degenerate prior: flat .*not a volume"):
        _init(scene)


def test_depth_unit_of_one_metre_is_refused(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene", depth_unit_m=1.0)  # values in millimetres
    with pytest.raises(InputError, match=r"depth.png: median depth 500 m with depth_unit_m 1 "):
        load_input(scene)
    result = r2s("run", str(scene))
    assert result.returncode == 2 and len(error_lines(result.stdout + result.stderr)) == 1
    assert not (scene / "init").exists()


def test_intrinsics_of_another_image_size_are_warned_about(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    assert load_input(scene).warnings == []
    cam_file = scene / "input" / "camera.json"
    cam = json.loads(cam_file.read_text())
    w, h = cam["width"], cam["height"]
    cam["K"] = (np.asarray(cam["K"]) * [[2], [2], [1]]).tolist()  # K of a 2x larger image
    cam_file.write_text(json.dumps(cam))
    warnings = load_input(scene).warnings
    assert len(warnings) == 1 and "principal point" in warnings[0]
    assert f"K scaled by 0.50 (K of a {2 * w} x {2 * h} image)" in warnings[0]
    # a crop: K of the right size, its principal point 30 % of the width left of centre
    cam["K"] = [[cam["K"][0][0] / 2, 0, (w - 1) / 2 - 0.3 * w],
                [0, cam["K"][1][1] / 2, (h - 1) / 2], [0, 0, 1]]
    cam_file.write_text(json.dumps(cam))
    warnings = load_input(scene).warnings
    assert len(warnings) == 1 and "unless the image was cropped" in warnings[0]
    assert "K scaled by" not in warnings[0]


def test_both_depth_files(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    png = np.asarray(Image.open(scene / "input" / "depth.png"), dtype=np.float32) * 0.001
    np.save(scene / "input" / "depth.npy", png)
    warnings = load_input(scene).warnings
    assert warnings == [f"{scene.resolve() / 'input'}: both depth.png and depth.npy exist; "
                        "they agree, depth.npy is used"]
    np.save(scene / "input" / "depth.npy", png * 1.5)  # 250 mm further everywhere on the table
    with pytest.raises(InputError, match=r"both depth.png and depth.npy exist and disagree "
                                         r"\(median \|difference\| 250 mm"):
        load_input(scene)


def test_one_pixel_instance_is_skipped_with_a_warning(tmp_path: Path):
    scene = write_two_boxes(tmp_path / "scene")
    masks = np.asarray(Image.open(scene / "input" / "masks.png")).copy()
    masks[5, 5] = 3
    Image.fromarray(masks).save(scene / "input" / "masks.png")
    loaded = load_input(scene)
    assert loaded.ids == [1, 2] and loaded.skipped_ids == [3]
    assert any("instance 3 has only 1 pixel with valid depth" in w for w in loaded.warnings)
    summary = _init(scene).summary
    assert summary["skipped"] == [3] and summary["objects"] == 2
    assert any("instance 3" in f for f in summary["flags"])
    masks[masks > 0] = 0
    masks[5, 5] = 3
    Image.fromarray(masks).save(scene / "input" / "masks.png")
    with pytest.raises(InputError, match=f"no instance has {MIN_MASK_PIXELS} pixels"):
        load_input(scene)


def test_non_finite_state_is_never_written(tmp_path: Path):
    state = SceneState(stage="x", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                       objects=[ObjectState(id=4, label="b", mesh="m.glb",
                                            world_from_object=np.eye(4).tolist())])
    state.objects[0].world_from_object[1][3] = float("nan")
    with pytest.raises(StageError, match=r"non-finite number at objects\[0\]"
                                         r".world_from_object\[1\]\[3\]"):
        write_state(tmp_path, state)
    assert not (tmp_path / "state.json").exists()


# ---- end to end: the real command line on a path with any characters ------------------------


@pytest.mark.slow
def test_unicode_path_runs_every_stage(reference_run: Path):
    assert UNICODE_DIR in str(reference_run)
    manifest = load_manifest(reference_run / "manifest.json")
    assert [n for n, r in manifest.stages.items() if r.status == "done"] == \
        ["init", "graph", "geomopt", "physopt", "texture", "export", "evaluate"]
    metrics = json.loads((reference_run / "evaluate" / "metrics.json").read_text())
    assert metrics["stability_ratio"] == 1.0
    assert not [p for p in reference_run.iterdir() if p.name.startswith((".tmp-", ".old-"))]


@pytest.mark.slow
def test_timing_lives_only_in_the_manifest(reference_run: Path):
    for name in ("geomopt/loss.json", "texture/metrics.json", "evaluate/metrics.json"):
        text = (reference_run / name).read_text()
        assert "seconds" not in text.replace("duration_s", ""), name
    assert load_manifest(reference_run / "manifest.json").stages["texture"].summary["seconds"]


@pytest.mark.slow
@pytest.mark.parametrize("with_gt", [False, True])
def test_nan_pose_in_export_is_refused_by_evaluate(reference_run: Path, tmp_path: Path,
                                                   with_gt: bool):
    scene = fresh_copy(reference_run, tmp_path / "nan scène" / "scene", with_outputs=True)
    if with_gt:
        shutil.copytree(scene / "export", scene / "gt")  # the export itself as ground truth
    path = scene / "export" / "scene.json"
    text = path.read_text()
    data = json.loads(text)
    data["objects"][1]["world_from_object"][0][3] = float("nan")
    path.write_text(json.dumps(data))  # Python writes the bare NaN token
    result = r2s("evaluate", str(scene))
    lines = error_lines(result.stdout + result.stderr)
    assert result.returncode == 2 and "Traceback" not in result.stdout + result.stderr
    assert len(lines) == 1
    assert "scene.json: non-finite number (NaN or inf) at objects[1].world_from_object[0][3]" \
        in lines[0]


@pytest.mark.slow
def test_kill_9_mid_run_then_rerun(reference_run: Path, tmp_path: Path):
    """A forced run killed inside a stage leaves its scratch folder; the next plain run removes
    it, keeps every up-to-date stage and ends with byte-identical outputs (this also shows the
    stages that reran before the kill wrote the same bytes as the reference run)."""
    scene = fresh_copy(reference_run, tmp_path / "kill" / "scene", with_outputs=True)
    before = stage_outputs(scene)
    proc = r2s_background("run", str(scene), "--force", *RUN_OPTIONS)
    deadline = time.monotonic() + 300
    while not list(scene.glob(".tmp-geomopt-*")) and time.monotonic() < deadline:
        assert proc.poll() is None, proc.stdout.read()
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert list(scene.glob(".tmp-geomopt-*"))
    result = r2s("run", str(scene), *RUN_OPTIONS)
    assert result.returncode == 0, result.stdout
    assert not [p for p in scene.iterdir() if p.name.startswith((".tmp-", ".old-"))]
    assert stage_outputs(scene) == before


@pytest.mark.slow
def test_concurrent_runs_never_corrupt_the_scene(reference_run: Path, tmp_path: Path):
    """Two ``r2s run`` started together and a third 3 s later (``--wait``): one runs, the
    other stops with one line naming it, the third waits and finds everything current; a
    final run changes nothing and the export equals a single run's byte for byte."""
    scene = fresh_copy(reference_run, tmp_path / "two runs" / "scene", with_outputs=False)
    a = r2s_background("run", str(scene), *RUN_OPTIONS)
    b = r2s_background("run", str(scene), *RUN_OPTIONS)
    time.sleep(3.0)
    c = r2s_background("run", str(scene), "--wait", "600", *RUN_OPTIONS)
    outs = {name: (p.wait(timeout=600), p.stdout.read()) for name, p in
            (("a", a), ("b", b), ("c", c))}
    codes = sorted(code for code, _ in (outs["a"], outs["b"]))
    assert codes == [0, SceneBusyError.exit_code], outs
    loser = next(text for code, text in (outs["a"], outs["b"]) if code != 0)
    lines = error_lines(loser)
    assert len(lines) == 1 and "scene is being written by pid" in lines[0]
    assert "Traceback" not in loser
    assert outs["c"][0] == 0 and "waiting up to 600 s" in outs["c"][1]
    assert "up to date" in outs["c"][1] and " ran " not in outs["c"][1]
    final = r2s("run", str(scene), *RUN_OPTIONS)
    assert final.returncode == 0
    ref = {k: v for k, v in stage_outputs(reference_run).items() if k.startswith("export/")}
    got = {k: v for k, v in stage_outputs(scene).items() if k.startswith("export/")}
    assert got == ref
    assert stage_outputs(scene) == stage_outputs(reference_run)
