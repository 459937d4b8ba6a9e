"""Headless command line, shared by ``python -m facecap`` and ``blender -b -P facecap_addon/cli.py -- ...``.

Commands
--------
retarget --config take.toml   solve a take onto its character with its [solve] strategy and write
                              .blend / weights CSV / report (/ the actor basis, [output] actor_basis);
                              a [source] video take solves from flow-PCA features (Ctrl-C cancels)
compare [options]             measure every strategy on the same synthetic takes (Markdown table)
demo [--out DIR]              retarget the bundled sample take and print its accuracy against ground truth
inspect FILE [options]        describe a capture file; non-zero exit with a one-line reason if it is bad
track --config take.toml      track video footage (LK points or dense flow) and write the 2D tracks CSV
tune --config take.toml       retune what the strategy learned from [tuning] corrections, store the new
                              library version ([tuning] out) and write the re-solved take
bench [--quick]               time the solve, the keying and the whole CLI, with ratios to naive baselines

Every expected failure (bad config, missing or malformed file) exits with status 1 and one line on
stderr naming the file and field; there is no traceback for those.
"""

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_CONFIG = ROOT / "sample_blends" / "sample_take.toml"


#: Take files larger than this are read in a forked child while Blender starts (smaller ones are
#: read in less time than the fork costs).
PARALLEL_READ_BYTES = 4 << 20
#: Weights (frames x shapes) above which the weights CSV is written in a forked child.
PARALLEL_WRITE_VALUES = 200_000


def _progress(message):
    print(f"facecap: {message}", file=sys.stderr, flush=True)


def run_retarget(config, *, quiet=False, solve=None):
    """Run a take config end to end; returns (RetargetResult, output paths dict).

    ``[tuning] library`` and ``[controls]`` are honoured (``tune_cli``). ``solve`` replaces the
    plain ``retarget`` call: (markers, character, settings, inputs, library info) -> (result,
    extra report entries); the ``tune`` command passes its retune there.
    """
    import dataclasses
    import warnings

    import numpy as np

    from ..solvers.capture.cleaning import clean
    from ..solvers.engine.split import release_freed_memory, run_beside
    from ..solvers.markers import UNIT_SCALE
    from ..solvers.errors import ConfigError
    from ..solvers.pipeline import retarget
    from ..solvers.io import import_markers
    from ..solvers.config.strategies import load_strategy_inputs

    if getattr(config, "video", None) is not None:  # [source] video: flow-PCA features, no markers
        if solve is not None:
            raise ConfigError("tuning a [source] video take is not supported yet", path=config.path, key="source.video")
        from .video_scene import run_flow_retarget

        return run_flow_retarget(config, quiet=quiet)
    say = (lambda _m: None) if quiet else _progress
    strategy = config.settings.strategy
    timings = {}
    t0 = time.perf_counter()
    if config.output_actor_basis is not None and config.output_actor_basis == config.actor_basis_path:
        raise ConfigError("must differ from [calibration] basis (a stored library is never overwritten)",
                          path=config.path, key="output.actor_basis")

    def read():
        t = time.perf_counter()
        markers, source, notes, cleaning = None, None, [], []
        if config.markers_path is not None:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                imported = import_markers(config.markers_path, units=config.units, fps=config.fps,
                                          **config.read_options)
            notes = list(dict.fromkeys([*imported.notes, *(str(w.message) for w in caught)]))
            cleaned = clean(imported.markers, config.clean)
            markers = cleaned.markers
            if markers.dim == 3 and markers.units in UNIT_SCALE:  # in metres here, as the solve reads it:
                markers = markers.to_units("m")  # one (F, M, 3) copy of the take for the whole run
            # one memory layout whichever process reads the take (a pickled array comes back
            # C-ordered, and sums over another layout round differently in the last bits)
            markers = dataclasses.replace(markers, positions=np.ascontiguousarray(markers.positions))
            cleaning = cleaned.report.summary().splitlines()
            source = {"format": imported.format, "units": imported.markers.units}  # not the raw take (a second copy)
        return markers, source, notes, cleaning, load_strategy_inputs(config), time.perf_counter() - t

    def open_blend():  # Blender's start-up (the first ``import bpy``) is in here
        t = time.perf_counter()
        return open_target(config, say), time.perf_counter() - t

    say(f"[1/5] reading markers {config.markers_path}" if config.markers_path is not None
        else f"[1/5] reading solved weights {config.weights_path}")
    # The take is read in a forked child while Blender starts and opens the character (measured on a
    # 36,000-frame CSV take: 1.0-1.5 s of reading beside 0.8-1.0 s of start-up); a bad file is read
    # again here, so its error is raised here.
    big = (config.markers_path is not None and config.markers_path.is_file()
           and config.markers_path.stat().st_size > PARALLEL_READ_BYTES)
    if big:
        (obj, t_open), taken = run_beside(open_blend, read)
    else:
        taken = read()
        obj, t_open = open_blend()
    markers, read_source, notes, cleaning, inputs, timings["read"] = taken

    import bpy

    from .scene_data import basis_from_object
    from .take import character_target

    t1 = time.perf_counter()
    # Only geometric samples the character at bound vertices; the others need its shape names and ranges.
    character = basis_from_object(obj, markers.names) if strategy == "geometric" else character_target(obj)
    timings["load_character"] = time.perf_counter() - t1 + t_open

    source = f"{markers.n_frames} frames from {markers.n_markers} markers" if markers is not None else (
        f"{len(inputs.weights.frames)} frames of {len(inputs.weights.names)} solved channels")
    say(f"[3/5] solving {source} x {len(character.shape_names if strategy == 'geometric' else character.names)} "
        f"shapes (strategy: {strategy})")
    from .tune_cli import finish_solve, prepare_solve

    character, inputs, settings, tuning_info = prepare_solve(config, character, inputs)
    if markers is not None and markers.dim == 2 and getattr(config, "projection", None) == "camera":
        from .video_scene import projection_for

        settings = dataclasses.replace(settings, projection=projection_for(bpy.context.scene, obj, "camera", config.camera_name))
    if solve is None:
        result, extra = retarget(markers, character, settings, inputs=inputs), {}
    else:
        result, extra = solve(markers, character, settings, inputs, tuning_info)
    result = finish_solve(config, result, markers.fps if markers is not None else inputs.weights.fps)

    outputs = {}
    if config.output_actor_basis is not None:
        actor_basis = getattr(result.fitted, "actor_basis", None)
        if actor_basis is None:
            raise ConfigError(f"strategy '{strategy}' has no actor basis to store (calibrated and refine do)",
                              path=config.path, key="output.actor_basis")
        config.output_actor_basis.parent.mkdir(parents=True, exist_ok=True)
        actor_basis.save_npz(config.output_actor_basis)
        outputs["actor_basis"] = str(config.output_actor_basis)
    if markers is not None:
        source = {"markers_file": str(config.markers_path),
                  "source": {**read_source, "fps": markers.fps,
                             "segments": {k: v for k, v in markers.segments.items()}}}
    else:
        track = inputs.weights
        source = {"weights_file": str(config.weights_path),
                  "source": {"format": track.format, "fps": track.fps, "timecode": track.timecode}}
    # The take's (F, M, 3) arrays are not needed for keying, whose F-curves are a long take's largest
    # memory (issue 18): freed before it (the stabilisation keeps its head poses).
    markers = None
    if getattr(result, "stabilise", None) is not None:
        result = dataclasses.replace(result, stabilise=result.stabilise.without_markers())
    release_freed_memory()
    outputs = key_and_write(config, obj, result, outputs=outputs, timings=timings, t0=t0, notes=notes, say=say,
                            report_fields={**source, "cleaning": cleaning, **tuning_info, **extra})
    return result, outputs


def open_target(config, say):
    """Open ``[target] blend`` (if given) and return ``[target] object``; the output .blend must not
    be the input one."""
    import bpy

    from ..solvers.errors import ConfigError, InputFileError

    if config.target_blend is not None:
        if not config.target_blend.is_file():
            raise InputFileError(config.target_blend, "file not found (config [target] blend)")
        say(f"[2/5] opening {config.target_blend}")
        bpy.ops.wm.open_mainfile(filepath=str(config.target_blend), load_ui=False)
    source_blend = Path(bpy.data.filepath).resolve() if bpy.data.filepath else None
    if config.output_blend is not None and source_blend is not None and config.output_blend == source_blend:
        raise ConfigError("must differ from the input .blend (inputs are never overwritten)", path=config.path,
                          key="output.blend")
    obj = bpy.data.objects.get(config.target_object)
    if obj is None:
        raise ConfigError(f"no object named '{config.target_object}' in the .blend", path=config.path,
                          key="target.object")
    return obj


def key_and_write(config, obj, result, *, outputs, timings, t0, notes, say, report_fields):
    """Key ``result`` as ``obj``'s solve layer and write ``[output]`` weights / .blend / report.

    ``outputs`` holds what was already written; ``report_fields`` are added to the JSON report
    (source, cleaning, tuning...); ``notes`` (reading) go before the solve's warnings.
    Returns ``outputs`` with the action and the written paths.
    """
    from ..solvers.engine.split import run_beside
    from ..solvers.io.files import write_json_atomic
    from ..solvers.io.csv import write_weights_csv
    from . import anim
    from .take import key_weights

    def key_and_save():
        t3 = time.perf_counter()
        say("[4/5] keying")
        action = key_weights(obj, result, anim.unique_action_name(config.action_name))
        timings["key"] = time.perf_counter() - t3
        say("[5/5] writing outputs")
        if config.output_blend is not None:
            _save_blend_atomic(config.output_blend)
        return action

    def write_weights():
        write_weights_csv(config.output_weights, result.frames, result.shape_names, result.weights)

    if config.output_weights is not None and result.weights.size > PARALLEL_WRITE_VALUES:
        # the weights CSV is written by a forked child while Blender keys and saves (measured on
        # 36,000 frames x 52 shapes: 0.4-0.6 s of writing beside 1.2 s); a failed child's file is
        # written again here
        action, _ = run_beside(key_and_save, write_weights, let_finish=True)
    else:
        action = key_and_save()
        if config.output_weights is not None:
            write_weights()
    outputs = {"action": action.name, **outputs}
    if config.output_weights is not None:
        outputs["weights"] = str(config.output_weights)
    if config.output_blend is not None:
        outputs["blend"] = str(config.output_blend)
    timings["total"] = time.perf_counter() - t0
    if config.output_report is not None:
        report = result.report()
        report["config"] = str(config.path)
        report.update(report_fields)
        report["outputs"] = outputs
        report["warnings"] = list(notes) + report["warnings"]
        report["timings_s"].update({k: round(v, 6) for k, v in timings.items()})
        write_json_atomic(config.output_report, report)
        outputs["report"] = str(config.output_report)
    for note in list(notes) + list(result.warnings):
        say(f"warning: {note}")
    return outputs


def _save_blend_atomic(path):
    import bpy

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}.blend")
    try:
        bpy.ops.wm.save_as_mainfile(filepath=str(tmp), copy=True, compress=True)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _cmd_retarget(args):
    from ..solvers.config import load_take_config

    config = load_take_config(args.config)
    result, outputs = run_retarget(config)
    import numpy as np

    ok = np.isfinite(result.residual_rms)
    residual = (f"mean residual {np.mean(result.residual_rms[ok]) * 1e3:.3f} mm ({result.residual_space} space)"
                if ok.any() else "no marker residual for this strategy")
    print(f"retargeted {result.frames.size} frames, {len(result.shape_names)} shapes (strategy: {result.strategy}); {residual}")
    for key, value in outputs.items():
        print(f"  {key}: {value}")
    return 0


def _cmd_demo(args):
    import dataclasses

    import numpy as np

    from ..solvers.config import load_take_config
    from ..solvers.io.csv import read_weights_csv
    from ..solvers.transforms import rotation_angle_deg

    out = Path(args.out).resolve()
    config = load_take_config(SAMPLE_CONFIG)
    config = dataclasses.replace(
        config,
        output_blend=out / "sample_take_retargeted.blend",
        output_weights=out / "sample_take_weights_solved.csv",
        output_report=out / "sample_take_report.json",
    )
    result, outputs = run_retarget(config)

    _, names, truth = read_weights_csv(ROOT / "sample_blends" / "sample_take_weights.csv")
    order = [names.index(n) for n in result.shape_names]
    err = result.weights - truth[:, order]
    rmse = float(np.sqrt(np.nanmean(err**2)))
    worst = np.nanmax(np.abs(err), axis=0)
    k = int(np.argmax(worst))

    from scipy.spatial.transform import Rotation

    head = np.loadtxt(ROOT / "sample_blends" / "sample_take_head.csv", delimiter=",", skiprows=1)
    true_rot = Rotation.from_rotvec(head[:, 1:4], degrees=True).as_matrix()
    ok = ~result.stabilise.flagged
    rot_err = rotation_angle_deg(result.stabilise.head_rotations()[ok] @ true_rot[ok].transpose(0, 2, 1))

    print("facecap demo: sample take -> sample character (strategy: geometric)")
    print(f"  frames {result.frames.size}, shapes {len(result.shape_names)}, markers {len(result.marker_names)}")
    print(f"  weights vs ground truth: RMSE {rmse:.4f}, max |error| {worst[k]:.4f} ({result.shape_names[k]})")
    print(f"  head rotation vs ground truth: median {np.median(rot_err):.3f} deg, max {rot_err.max():.3f} deg")
    print(f"  actor-to-character scale {result.alignment.scale:.4f}")
    print(f"  mean residual {np.nanmean(result.residual_rms) * 1e3:.3f} mm, solve {result.timings['solve']:.3f} s")
    for key, value in outputs.items():
        print(f"  {key}: {value}")
    return 0


def _cmd_inspect(args):
    from ..solvers.tools.inspect import main as inspect_main

    return inspect_main(args.rest)


def _cmd_compare(args):
    from ..solvers.tools.compare import main as compare_main

    return compare_main(args.rest)


def _cmd_track(args):
    from ..solvers.video.cli import main as track_main

    return track_main(args.rest)


def _cmd_tune(args):
    from .tune_cli import cmd_tune

    return cmd_tune(args)


def _cmd_bench(args):
    from ..solvers.tools.bench import run_benchmarks

    frames = 3600 if args.quick else 36000
    for row in run_benchmarks(quick=args.quick):
        print(_bench_line(row), flush=True)
    from .bench import bench_cli_retarget, bench_keying

    print(_bench_line(bench_keying(frames=frames)), flush=True)
    print(_bench_line(bench_cli_retarget(frames=frames)), flush=True)
    return 0


def _bench_line(row):
    ratio = f"{row['ratio']:.0f}x vs {row['baseline_seconds']:.1f} s baseline" if row.get("ratio") else "no baseline"
    return f"{row['name']}: {row['seconds']:.3f} s median; {ratio}; goal {row['goal']}; {row['note']}"


def build_parser():
    parser = argparse.ArgumentParser(prog="facecap", description="Performance-driven facial retargeting.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("retarget", help="retarget a take described by a TOML config")
    p.add_argument("--config", required=True, help="take config (.toml)")
    p.set_defaults(func=_cmd_retarget)
    p = sub.add_parser("demo", help="retarget the bundled sample take and print its accuracy")
    p.add_argument("--out", default="facecap-demo", help="output folder (default: ./facecap-demo)")
    p.set_defaults(func=_cmd_demo)
    p = sub.add_parser("inspect", help="describe a marker or weights file (markers, frames, rate, units, gaps, segments)",
                       add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_inspect)
    p = sub.add_parser("compare", help="accuracy and time of every strategy on the same synthetic takes (Markdown)",
                       add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_compare)
    p = sub.add_parser("track", help="track markers or dense flow in video footage and write 2D tracks", add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_track)
    p = sub.add_parser("tune", help="retune the strategy from an animator's corrected frames and re-solve the take")
    p.add_argument("--config", required=True, help="take config (.toml) with [tuning] corrections")
    p.set_defaults(func=_cmd_tune)
    p = sub.add_parser("bench", help="time the solver, keying and the whole CLI against naive baselines")
    p.add_argument("--quick", action="store_true", help="3,600 frames instead of 36,000")
    p.set_defaults(func=_cmd_bench)
    return parser


def main(argv=None):
    """Entry point; returns the process exit status."""
    from ..solvers.errors import FacecapError

    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        if args.command not in ("compare", "track", "inspect"):  # these forward their options
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        args.rest = extra + list(args.rest)
    if args.command in BATCH_COMMANDS:
        keep_freed_memory()
    try:
        return args.func(args)
    except FacecapError as exc:
        from ..solvers.video.reading import Cancelled

        if isinstance(exc, Cancelled):  # Ctrl-C during a video take's flow: nothing was written
            print(f"facecap: {exc}; nothing written", file=sys.stderr)
            return 130
        print(f"facecap: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("facecap: interrupted", file=sys.stderr)
        return 130


#: Commands that run one take through and exit: they keep freed memory for reuse (``keep_freed_memory``).
BATCH_COMMANDS = ("retarget", "tune", "demo")


def keep_freed_memory():
    """Ask glibc's allocator to keep freed memory in the process for reuse instead of returning it
    to the system (mmap threshold 32 MB, trim threshold 1 GB, top pad 64 MB). A take's solve
    allocates and frees arrays of tens of MB over and over; returned memory comes back as fresh
    pages, each one a page fault when first written (measured on the 36,000-frame CLI take: 1.1
    million faults, 5-8 s of system CPU; with this 0.67-0.81 million, 3.7-5.3 s; peak memory +3 %).
    For one-shot batch processes only: a Blender session should give memory back. Elsewhere (no
    glibc) it does nothing. Returns whether the settings were taken."""
    import ctypes

    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3  # from malloc.h
    settings = ((m_mmap_threshold, 32 << 20), (m_trim_threshold, 1 << 30), (m_top_pad, 64 << 20))
    return all([bool(mallopt(option, value)) for option, value in settings])  # a list: every setting is applied


def _script_package():
    """The package this file belongs to, when run as a script (``blender -b -P .../cli.py``)."""
    import importlib.util

    for name, module in list(sys.modules.items()):
        if name.startswith("bl_ext.") and name.endswith(".facecap") and Path(module.__file__).parent == ROOT:
            return module
    spec = importlib.util.spec_from_file_location("facecap", ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["facecap"] = module
    spec.loader.exec_module(module)
    return module


if __name__ == "__main__":
    # Blender passes its own arguments; ours follow "--".
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    package = _script_package()
    import importlib

    cli = importlib.import_module(package.__name__ + ".facecap_addon.cli")
    sys.exit(cli.main(argv))
