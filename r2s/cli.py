"""The ``r2s`` command line: parse, then call the stage. No logic lives here.

Every stage command takes the scene directory and ``--set key=value`` options (listed by
``--help``); expected errors print one red line and exit non-zero.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable, List, Optional

import typer

from r2s import __version__
from r2s.console import console, print_error
from r2s.errors import R2SError

app = typer.Typer(no_args_is_help=True,
                  help="r2s: a physically consistent simulation twin of a cluttered tabletop "
                       "from one RGB-D image and instance masks.")

SET_HELP = ("Stage option as key=value (repeatable), applied to the options the stage last ran "
            "with (else the defaults); see the list below.")
JSON_HELP = ("Print the stage summary and the metrics as one JSON document on stdout "
             "(tables and progress go to stderr).")
WAIT_HELP = ("When another r2s process writes the scene: wait up to this many seconds for it "
             "(default 0: stop at once with one line naming it).")


def _version_callback(value: bool) -> None:
    if value:
        console.print(f"r2s {__version__}", highlight=False)
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version_callback,
                                 is_eager=True, help="Print the version and exit."),
) -> None:
    """r2s: a physically consistent simulation twin of a cluttered tabletop from one RGB-D
    image and instance masks."""


def _options_epilog(stage_name: str) -> str:
    from r2s.cli_help import options_epilog  # imports the stage (and torch): --help only

    return options_epilog(stage_name)


def _run_and_report(scene_dir: Path, as_json: bool, call: Callable) -> None:
    """Run ``call(progress_factory, on_warning)`` -> results, then print the tables and the
    closing line, or (``--json``) only the JSON document on stdout."""
    from r2s.cli_output import (emit_json, no_progress, print_results, print_where,
                                results_document, stdout_reserved_for_json)
    from r2s.console import print_warning, stage_progress

    said: list[str] = []

    def warn(message: str) -> None:
        if message not in said:
            said.append(message)
            print_warning(message)

    if as_json:
        with stdout_reserved_for_json() as out:
            results = call(no_progress, warn)
            print_results(results, said)  # on stderr
            emit_json(out, results_document(scene_dir, results))
        return
    results = call(stage_progress, warn)
    print_results(results, said)
    print_where(scene_dir)


def _parse_sets(sets: Optional[List[str]]) -> dict:
    out: dict = {}
    for item in sets or []:
        if "=" not in item:
            raise R2SError(f"--set {item!r}: expected key=value")
        key, value = item.split("=", 1)
        out[key.strip()] = value.strip()
    return out


def _run_one_stage(scene_dir: Path, stage_name: str, overrides: dict, as_json: bool,
                   wait_s: float = 0.0) -> None:
    from r2s.runner.pipeline import run_single_stage

    _run_and_report(scene_dir, as_json, lambda progress_factory, on_warning: [run_single_stage(
        scene_dir, stage_name, overrides, progress_factory=progress_factory,
        on_warning=on_warning, wait_s=wait_s)])


def _make_stage_command(stage_name: str, summary: str) -> Callable:
    def command(
        scene_dir: Path = typer.Argument(..., help="Scene directory (holds input/)."),
        set_: Optional[List[str]] = typer.Option(None, "--set", help=SET_HELP),
        as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
        wait: float = typer.Option(0.0, "--wait", min=0, help=WAIT_HELP),
    ) -> None:
        _run_one_stage(scene_dir, stage_name, _parse_sets(set_), as_json, wait)

    command.__doc__ = summary
    command.__name__ = f"cmd_{stage_name}"
    return command


_STAGE_HELP = {
    "init": "Back-project masks, fit the support plane, register or complete each object.",
    "graph": "Build the contact graph (support parse tree + proximity edges).",
    "geomopt": "SDF-based penetration / contact / anchor pose optimisation.",
    "physopt": "Hierarchical physics-constrained optimisation of pose, COM, mass, friction.",
    "texture": "Photometric texture refinement with a total-variation prior.",
    "export": "Write export/ (scene.json, meshes, convex collision pieces, URDFs).",
    "evaluate": "Re-simulate export/ in PyBullet; stability, geometry and rendering metrics.",
    "diagnose": "Trace residuals to missing model effects; report error before and after.",
}

_WANTS_HELP = "--help" in sys.argv[1:]
for _name, _summary in _STAGE_HELP.items():
    if _name in ("physopt", "evaluate"):
        continue  # have their own commands below (add --only, --engine)
    # The option list imports the stage (and torch); build it only when help is asked for.
    _epilog = _options_epilog(_name) if _WANTS_HELP and _name in sys.argv[1:] else None
    app.command(name=_name, help=_summary, epilog=_epilog)(_make_stage_command(_name, _summary))


@app.command(name="physopt", help=_STAGE_HELP["physopt"],
             epilog=_options_epilog("physopt") if _WANTS_HELP and "physopt" in sys.argv[1:] else None)
def cmd_physopt(
    scene_dir: Path = typer.Argument(..., help="Scene directory (holds input/)."),
    only: Optional[int] = typer.Option(None, "--only", help="Rerun only this object id and "
                                                          "the objects it supports."),
    set_: Optional[List[str]] = typer.Option(None, "--set", help=SET_HELP),
    as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
    wait: float = typer.Option(0.0, "--wait", min=0, help=WAIT_HELP),
) -> None:
    overrides = _parse_sets(set_)
    # ``--only`` is one run's choice: without it, the whole scene (not a recorded --only)
    overrides.setdefault("only", "null" if only is None else str(only))
    if only is not None:
        overrides["only"] = str(only)
    _run_one_stage(scene_dir, "physopt", overrides, as_json, wait)


@app.command(name="evaluate", help=_STAGE_HELP["evaluate"],
             epilog=_options_epilog("evaluate") if _WANTS_HELP and "evaluate" in sys.argv[1:]
             else None)
def cmd_evaluate(
    scene_dir: Path = typer.Argument(..., help="Scene directory (holds export/)."),
    engine: Optional[str] = typer.Option(
        None, "--engine", help="Judge engine: pybullet (default) or mujoco (export/scene.xml); "
                               "the same as --set engine=..."),
    set_: Optional[List[str]] = typer.Option(None, "--set", help=SET_HELP),
    as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
    wait: float = typer.Option(0.0, "--wait", min=0, help=WAIT_HELP),
) -> None:
    overrides = _parse_sets(set_)
    if engine is not None:
        overrides["engine"] = engine
    _run_one_stage(scene_dir, "evaluate", overrides, as_json, wait)


@app.command()
def run(
    scene_dir: Path = typer.Argument(..., help="Scene directory (holds input/)."),
    force: bool = typer.Option(False, "--force", help="Rerun every stage."),
    until: Optional[str] = typer.Option(None, help="Stop after this stage."),
    skip: Optional[List[str]] = typer.Option(None, help="Stage to leave out (repeatable)."),
    set_: Optional[List[str]] = typer.Option(None, "--set",
                                             help="stage.key=value option (repeatable)."),
    as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
    wait: float = typer.Option(0.0, "--wait", min=0, help=WAIT_HELP),
) -> None:
    """Run every stage whose inputs or options changed, and skip the rest."""
    overrides = _parse_sets(set_)

    def call(progress_factory: Callable, on_warning: Callable) -> list:
        if not force:  # a finished scene answers without importing any stage
            from r2s.runner.noop import quick_run

            quick = quick_run(scene_dir, until, list(skip or []), overrides, wait_s=wait,
                              notify=on_warning)
            if quick is not None:
                for warning in quick[1]:
                    on_warning(warning)
                return quick[0]
        from r2s.runner.pipeline import run_pipeline

        return run_pipeline(scene_dir, force=force, until=until, skip=list(skip or []),
                            overrides=overrides, progress_factory=progress_factory,
                            on_warning=on_warning, wait_s=wait)

    _run_and_report(scene_dir, as_json, call)


def _synth_epilog() -> Optional[str]:
    if not (_WANTS_HELP and "synth" in sys.argv[1:]):
        return None
    from r2s.synth.options import set_help

    return set_help()


@app.command(epilog=_synth_epilog())
def synth(
    out_dir: Path = typer.Argument(..., help="Scene directory to create."),
    objects: str = typer.Option("ycb", help="Object set: ycb, pybullet, mixed, or a "
                                            "comma-separated list of catalogue names."),
    count: int = typer.Option(6, help="Number of objects (1-15)."),
    seed: int = typer.Option(0, help="Random seed."),
    noise: float = typer.Option(1.0, help="Depth noise level (0 = perfect depth)."),
    effect: Optional[List[str]] = typer.Option(None, help="Injected effect NAME=VALUE "
                                               "(repeatable); recorded only in gt/."),
    width: int = typer.Option(640, help="Image width in pixels."),
    height: int = typer.Option(480, help="Image height in pixels."),
    push: bool = typer.Option(False, "--push", help="Also push one object on the ground truth "
                                                    "and write what the camera saw after it "
                                                    "(input/interaction/)."),
    set_: Optional[List[str]] = typer.Option(
        None, "--set", help="Synth option as key=value (repeatable), e.g. realism=realsense "
                            "(a realistic RealSense-like capture); see the list below."),
) -> None:
    """Make a benchmark scene: settled clutter, rendered RGB-D and masks, priors, gt/."""
    from r2s.synth.options import SynthOptions, options_from_command_line

    given = dict(objects=objects, count=count, seed=seed, noise=noise, width=width,
                 height=height, push=push)
    defaults = SynthOptions.model_fields
    explicit = {k: v for k, v in given.items() if v != defaults[k].default}
    explicit["effects"] = _parse_sets(effect)
    opts = options_from_command_line(explicit, _parse_sets(set_))
    from r2s.synth.generate import synthesize  # (imports PyBullet: after the checks)
    from r2s.console import stage_progress

    with stage_progress("synth") as progress:
        summary = synthesize(out_dir, opts, progress=progress)
    console.print(f"[green]wrote[/green] {out_dir} ({summary.get('objects', '?')} objects)")


@app.command()
def predict(
    scene_dir: Path = typer.Argument(..., help="Scene directory with export/."),
    action: Optional[Path] = typer.Option(
        None, "--action", help="Push action JSON (see docs/interaction.md); default: the "
                               "observed push input/interaction/push.json."),
) -> None:
    """Replay a pusher trajectory on export/ in PyBullet; writes predict/.

    With the observed push (input/interaction/), predict/ also holds the error against
    the observed outcome."""
    from r2s.console import print_table
    from r2s.interaction.predict import predict as run_predict

    summary = run_predict(scene_dir, action)
    err = summary.get("error", {})
    ucd = {o["id"]: o["ucd_mm"] for o in err.get("objects", [])}
    pose = {o["id"]: o for o in err.get("pose", [])}

    def cell(value: Optional[float]) -> str:
        return "-" if value is None else f"{value:.1f}"

    rows = [[str(o["id"]) + (" (pushed)" if o["id"] == err.get("pushed_id") else ""),
             f"{o['displacement_m'] * 1000:.1f}", cell(ucd.get(o["id"])),
             cell(pose.get(o["id"], {}).get("translation_mm")),
             cell(pose.get(o["id"], {}).get("rotation_deg"))] for o in summary["objects"]]
    title = "predicted push"
    if err.get("ucd_mm") is not None:
        title += f": UCD {err['ucd_mm']:.1f} mm"
    print_table(title, ["object", "moved [mm]", "UCD [mm]", "pose err [mm]", "pose err [deg]"],
                rows)


@app.command()
def declutter(
    scene_dir: Path = typer.Argument(..., help="Scene directory with export/."),
) -> None:
    """Plan a removal order (children first) in which each removal leaves the rest at rest."""
    from r2s.console import print_table
    from r2s.interaction.declutter import declutter as run_declutter

    report = run_declutter(scene_dir)
    gt = {s["id"]: s for s in report.get("ground_truth", {}).get("steps", [])}
    rows = [[str(k + 1), str(s["id"]), f"{s['translation_m'] * 1000:.1f}",
             "yes" if s["at_rest"] else "no",
             ("yes" if gt[s["id"]]["at_rest"] else "no") if s["id"] in gt else "-"]
            for k, s in enumerate(report["steps"])]
    print_table(f"removal order (success {report['success_rate']:.0%})",
                ["step", "object", "disturbance [mm]", "rest at rest", "on gt"], rows)


@app.command()
def report(
    scene_dirs: List[Path] = typer.Argument(..., help="Scene directories with evaluate/metrics.json."),
    out: Optional[Path] = typer.Option(None, help="Also write the table as markdown here."),
    label: str = typer.Option("r2s", help="Row label for the markdown table."),
) -> None:
    """Aggregate evaluate/metrics.json of many scenes into one table."""
    from r2s.batch import aggregate_metrics

    aggregate_metrics(scene_dirs, out=out, label=label)


@app.command()
def batch(
    root: Path = typer.Argument(..., help="Folder searched at any depth for scenes (a scene is "
                                          "a folder holding input/)."),
    jobs: int = typer.Option(1, "--jobs", "-j", min=1, help="Scenes run at once."),
    executor: str = typer.Option("local", "--executor",
                                 help="local (processes on this machine) or ray (a local Ray "
                                      "instance, or the cluster named by RAY_ADDRESS)."),
    threads: Optional[int] = typer.Option(
        None, "--threads", min=1, help="Torch/BLAS threads per job (default: CPU cores / "
                                       "jobs)."),
    set_: Optional[List[str]] = typer.Option(None, "--set",
                                             help="stage.key=value option (repeatable)."),
    skip: Optional[List[str]] = typer.Option(None, help="Stage to leave out (repeatable)."),
    out: Optional[Path] = typer.Option(None, help="Report folder (default ROOT): report.md "
                                                  "and report.csv."),
    label: str = typer.Option("r2s", help="Row label of the aggregate."),
) -> None:
    """Run every scene under ROOT (any depth, resumable); write report.md and report.csv.

    Each scene is an 'r2s run' (up-to-date stages are skipped); the reports have one row
    per scene and the aggregate of 'r2s report'. See docs/batch.md for clusters."""
    from r2s.runner.batch import BatchConfig, run_batch

    config = BatchConfig(jobs=jobs, executor=executor, threads=threads,
                         overrides=_parse_sets(set_), skip=tuple(skip or ()), label=label)
    outcome = run_batch(root, config, out_dir=out, progress=_batch_line)
    from r2s.console import print_table

    rows = [[str(s.scene), "ok" if s.ok else f"failed: {s.error}", f"{s.seconds:.1f}"]
            for s in outcome.scenes]
    print_table(f"batch: {len(outcome.scenes)} scenes, {outcome.seconds:.1f} s",
                ["scene", "status", "seconds"], rows)
    console.print(f"report: {outcome.report_md} and {outcome.report_csv}", soft_wrap=True,
                  highlight=False, markup=False)
    if outcome.failed:
        raise R2SError(f"{outcome.failed} of {len(outcome.scenes)} scenes failed; see the "
                       f"run.log in each")


def _batch_line(message: str) -> None:
    console.print(message, soft_wrap=True, highlight=False, markup=False)


@app.command()
def view(
    scene_dir: Path = typer.Argument(..., help="Scene directory with export/ (r2s run first)."),
    port: int = typer.Option(8080, help="Port to serve on."),
    host: str = typer.Option("127.0.0.1",
                             help="Address to bind (0.0.0.0 to share on the network)."),
    screenshot: Optional[Path] = typer.Option(
        None, help="Save a picture of the page (headless Chromium) to this PNG and exit."),
) -> None:
    """Look at the scene in the browser: observed points, reconstruction, collision pieces,
    contact graph, and a player of the judge's rollout (objects that moved in red)."""
    from r2s.viewer.cli_entry import view_scene

    view_scene(scene_dir, host=host, port=port, screenshot=screenshot)


def main(argv: Optional[List[str]] = None) -> None:
    """Console-script entry point: expected errors and usage mistakes become one red line
    and an exit code (usage: 2); a bug keeps its traceback."""
    import logging

    logging.getLogger("trimesh").setLevel(logging.ERROR)  # its sampling chatter is not news
    from r2s.cli_help import tidy_help

    try:
        command = typer.main.get_command(app)
        tidy_help(command)
        command.main(args=argv, prog_name="r2s", standalone_mode=False)
    except R2SError as exc:
        print_error(str(exc))
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        print_error("interrupted; the previous results are intact")
        sys.exit(130)
    except SystemExit:
        raise
    except Exception as exc:
        from r2s.cli_help import usage_error

        found = usage_error(exc)
        if found is None:
            raise
        message, code = found
        if message:
            print_error(message)
        sys.exit(code)


if __name__ == "__main__":
    main()
