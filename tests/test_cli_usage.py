"""The command line's usage mistakes, --version, help text and --json.

Each usage mistake prints one line on stderr, nothing on stdout, and exits 2, with no
traceback (issue 17). Most run in-process through :func:`r2s.cli.main`; one subprocess
checks the installed entry point's behaviour as a user sees it.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from r2s import __version__
from r2s.cli import main

REPO = Path(__file__).resolve().parents[1]


def run_main(argv: list[str], capsys) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as info:
        main(argv)
        raise SystemExit(0)
    out, err = capsys.readouterr()
    return int(info.value.code or 0), out, err


def assert_usage_error(code: int, out: str, err: str, *needles: str) -> None:
    assert code == 2, (code, out, err)
    assert out == ""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


@pytest.mark.parametrize("argv, needles", [
    (["nosuchcmd"], ["No such command 'nosuchcmd'", "r2s --help"]),
    (["run"], ["Missing argument", "scene_dir", "r2s run --help"]),
    (["run", "somewhere", "--bogus"], ["No such option: --bogus"]),
    (["report"], ["Missing argument", "scene_dirs"]),
    (["batch", "somewhere", "--executor", "slurm"], ["unknown executor 'slurm'", "local, ray"]),
])
def test_usage_mistake_is_one_line_and_exit_2(argv, needles, capsys, tmp_path):
    code, out, err = run_main([a if a != "somewhere" else str(tmp_path) for a in argv], capsys)
    assert_usage_error(code, out, err, *needles)


def test_misspelt_stage_in_set_names_the_stages(tiny_scene, capsys):
    code, out, err = run_main(["run", str(tiny_scene), "--set", "phsyopt.x=1"], capsys)
    assert_usage_error(code, out, err, "unknown stage 'phsyopt'",
                       "init, graph, geomopt, physopt, texture, export, evaluate")
    assert not (tiny_scene / "manifest.json").exists()  # nothing ran


def test_unknown_option_in_set_names_the_options(tiny_scene, capsys):
    code, out, err = run_main(["run", str(tiny_scene), "--set", "graph.sead=3"], capsys)
    assert_usage_error(code, out, err, "graph has no option 'sead'", "seed", "samples")
    assert not (tiny_scene / "manifest.json").exists()
    code, out, err = run_main(["graph", str(tiny_scene), "--set", "sead=3"], capsys)
    assert_usage_error(code, out, err, "graph has no option 'sead'", "seed")



def test_bad_option_value_in_set_is_a_usage_error(tiny_scene, capsys):
    """A value the option's type refuses is a usage mistake too: exit 2, one line."""
    code, out, err = run_main(["run", str(tiny_scene), "--set", "graph.seed=maybe"], capsys)
    assert_usage_error(code, out, err, "graph option seed")
    assert not (tiny_scene / "manifest.json").exists()
    code, out, err = run_main(["diagnose", str(tiny_scene), "--set", "table_height=maybe"],
                              capsys)
    assert_usage_error(code, out, err, "diagnose option table_height", "'auto', 'on' or 'off'")

def test_version(capsys):
    code, out, err = run_main(["--version"], capsys)
    assert code == 0 and out.strip() == f"r2s {__version__}" and err == ""


def test_entry_point_usage_error_has_no_traceback():
    proc = subprocess.run([sys.executable, "-m", "r2s.cli", "nosuchcmd"], capture_output=True,
                          text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [
        "error: No such command 'nosuchcmd'. (see 'r2s --help')"]


def test_help_is_light_and_shows_flags_and_defaults():
    """``r2s --help`` imports neither torch nor numpy; flags show without a type; a stage's
    option list shows default_factory defaults (not PydanticUndefined) and no private name."""
    probe = ("import sys; from r2s.cli import main\n"
             "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
             "print('HEAVY', sorted(m for m in ('torch', 'numpy', 'pybullet', 'trimesh') "
             "if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "HEAVY []" in proc.stdout
    assert "--install-completion" in proc.stdout and "--version" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "r2s.cli", "diagnose", "--help"],
                          capture_output=True, text=True, cwd=REPO, timeout=300,
                          env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    assert "PydanticUndefined" not in proc.stdout
    assert "effects=<list> (default [])" in proc.stdout
    assert "apply=<true|false> (default false)" in proc.stdout
    assert "<bool>" not in proc.stdout  # --json, --help are flags
    assert "--json" in proc.stdout


def test_physopt_help_names_no_private_function():
    proc = subprocess.run([sys.executable, "-m", "r2s.cli", "physopt", "--help"],
                          capture_output=True, text=True, cwd=REPO, timeout=300,
                          env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    assert "._" not in proc.stdout and " _" not in proc.stdout.replace("  ", " ")
    assert "convex_method=<vhacd|coacd> (default 'vhacd')" in proc.stdout


def test_json_prints_only_the_document(tiny_scene):
    """``r2s run --json``: stdout parses as JSON, its stage entries and metrics are those
    the scene's manifest and metrics.json recorded; the tables went to stderr."""
    proc = subprocess.run(
        [sys.executable, "-m", "r2s.cli", "run", str(tiny_scene), "--skip", "geomopt",
         "--skip", "physopt", "--skip", "texture", "--set", "evaluate.render=false", "--json"],
        capture_output=True, text=True, cwd=REPO, timeout=600)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)  # nothing else on stdout (not even PyBullet's banner)
    assert [s["name"] for s in doc["stages"]] == ["init", "graph", "export", "evaluate"]
    assert all(s["ran"] and s["reason"] == "never ran" for s in doc["stages"])
    manifest = json.loads((tiny_scene / "manifest.json").read_text())
    for s in doc["stages"]:
        assert s["summary"] == manifest["stages"][s["name"]]["summary"]
        assert s["seconds"] == pytest.approx(manifest["stages"][s["name"]]["seconds"], abs=2e-3)
    assert doc["metrics"] == json.loads((tiny_scene / "evaluate" / "metrics.json").read_text())
    assert doc["export"] == str(tiny_scene / "export")
    assert str(tiny_scene / "init" / "init.png") in doc["pictures"]
    assert "stages" in proc.stderr  # the table

    # without --json: the tables, then the closing line naming export/ and the pictures
    proc = subprocess.run([sys.executable, "-m", "r2s.cli", "run", str(tiny_scene), "--skip",
                           "geomopt", "--skip", "physopt", "--skip", "texture"],
                          capture_output=True, text=True, cwd=REPO, timeout=600,
                          env={"COLUMNS": "300", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    last = proc.stdout.strip().splitlines()[-1]
    assert last.startswith(f"export: {tiny_scene}/export/; pictures: "), last
    assert f"{tiny_scene}/init/" in last and f"{tiny_scene}/graph/" in last
