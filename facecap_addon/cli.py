"""Headless command line, shared by ``python -m facecap`` and ``blender -b -P facecap_addon/cli.py -- ...``:
argument parsing and dispatch. The commands, their one-line summaries and how they print and fail are in
``headless/commands.py``; every command's ``--help`` is docs/commands.md.
"""

import importlib
import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _script_package():
    """The package this file belongs to, when run as a script (``blender -b -P .../cli.py``)."""
    for name, module in list(sys.modules.items()):
        if name.startswith("bl_ext.") and name.endswith(".facecap") and Path(module.__file__).parent == ROOT:
            return module
    spec = importlib.util.spec_from_file_location("facecap", ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["facecap"] = module
    spec.loader.exec_module(module)
    return module


if __name__ == "__main__" and not __package__:
    # Run as a script: import the package, then its own copy of this module (relative imports need it).
    # Blender passes its own arguments; ours follow "--".
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    cli = importlib.import_module(_script_package().__name__ + ".facecap_addon.cli")
    sys.exit(cli.main(argv))

# Imported here, after the script guard: as a script this file has no package for them.
import argparse  # noqa: E402
import contextlib  # noqa: E402
import ctypes  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import tomllib  # noqa: E402

import numpy as np  # noqa: E402

from ..solvers.config import load_take_config  # noqa: E402
from ..solvers.errors import FacecapError  # noqa: E402
from ..solvers.tools import config_docs  # noqa: E402
from ..solvers.tools.bench.accuracy_bench import main as accuracy_main  # noqa: E402
from ..solvers.tools.bench.bench import goal_verdict, run_benchmarks  # noqa: E402
from ..solvers.tools.build_extension import main as build_extension_main  # noqa: E402
from ..solvers.tools.bench.clean_bench import bench_clean  # noqa: E402
from ..solvers.tools.convert import main as convert_main  # noqa: E402
from ..solvers.tools.inspect import main as inspect_main  # noqa: E402
from ..solvers.tools.landmark_models import main as landmark_models_main  # noqa: E402
from ..solvers.tools.template import main as template_main  # noqa: E402
from ..solvers.video.cli import main as track_main  # noqa: E402
from ..solvers.video.reading import Cancelled  # noqa: E402
from .headless import console  # noqa: E402
from .headless.commands import BATCH_COMMANDS, BLENDER_COMMANDS, COMMANDS, FORWARDING  # noqa: E402
from .batch.batch import run_batch  # noqa: E402
from .batch.batch_worker import serve  # noqa: E402
from .bench.bench import MEMORY_FRAMES, bench_batch, bench_cli_retarget, bench_keying, bench_memory  # noqa: E402
from .headless.demo import run_demo  # noqa: E402
from .headless.headless import progress_line, run_take  # noqa: E402
from .bench.landmark_bench import main as landmark_bench_main  # noqa: E402
from .render.review import review_flags  # noqa: E402


def _cmd_retarget(args):
    config = review_flags(load_take_config(args.config), args.html, args.truth)
    result, outputs = run_take(config, replace=args.replace, overwrite=args.overwrite)

    ok = np.isfinite(result.residual_rms)
    residual = (f"mean residual {np.mean(result.residual_rms[ok]) * 1e3:.3f} mm ({result.residual_space} space)"
                if ok.any() else "no marker residual for this strategy")
    print(f"retargeted {result.frames.size} frames, {len(result.shape_names)} shapes (strategy: {result.strategy}); "
          f"{residual}", file=console.stdout())
    for key, value in outputs.items():
        print(f"  {key}: {value}", file=console.stdout())
    return 0


def _cmd_batch(args):
    return run_batch(args)


def _batch_worker(argv):
    """``batch-worker --fds IN,OUT``: started by ``batch`` (``batch_pool``), never by hand, so not in any help."""
    parser = argparse.ArgumentParser(prog="facecap batch-worker", description="A batch's worker process (internal).")
    parser.add_argument("--fds", required=True)
    args = parser.parse_args(argv)
    keep_freed_memory()
    console.configure(0)
    fd_in, fd_out = (int(v) for v in args.fds.split(","))
    return serve(fd_in, fd_out)


def _cmd_demo(args):
    return run_demo(Path(args.out))


def _cmd_inspect(args):
    return inspect_main(args.rest, parents=[OUTPUT_OPTIONS])


def _cmd_compare(args):
    from ..solvers.tools.compare import main as compare_main  # loads scipy

    return compare_main(args.rest, parents=[OUTPUT_OPTIONS])


def _cmd_config_docs(args):
    return config_docs.main(args.rest, parents=[OUTPUT_OPTIONS], commands=command_helps)


def command_helps(width=100):
    """[(command, its --help text)]: the top level ("") then every command, as a terminal ``width`` wide
    shows them (the command reference, docs/commands.md)."""
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)  # argparse wraps to the terminal's width
    try:
        out = []
        for command in ["", *COMMANDS]:
            text = io.StringIO()
            with contextlib.redirect_stdout(text), contextlib.suppress(SystemExit):
                main([command, "--help"] if command else ["--help"])
            out.append((command, text.getvalue()))
        return out
    finally:
        if previous is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = previous


def _cmd_track(args):
    return track_main(args.rest, parents=[OUTPUT_OPTIONS])


def _cmd_tune(args):
    config = load_take_config(args.config)
    result, outputs = run_take(config, tune=True, overwrite=args.overwrite)
    tuned = result.retune
    v = tuned.version
    print(f"retuned '{result.strategy}' from {len(tuned.frames)} corrected frame(s): corrected RMSE "
          f"{tuned.corrected_rmse_before:.4f} -> {tuned.corrected_rmse_after:.4f}; other frames moved "
          f"{tuned.others_moved:.1%}", file=console.stdout())
    print(f"  new version: {v.name} (parent {v.parent})" if tuned.changed else
          f"  library unchanged ({v.name}); no new version written", file=console.stdout())
    for note in tuned.notes:
        print(f"  note: {note}", file=console.stdout())
    for key, value in outputs.items():
        print(f"  {key}: {value}", file=console.stdout())
    return 0


def _cmd_docs_images(args):
    from .render.docs_images import docs_images_command  # imports bpy (and bmesh) at once: only for this command

    return docs_images_command(args, say=progress_line, out=console.stdout())


def _cmd_rig_bench(args):
    from .bench.rig_bench_run import rig_bench  # imports bpy at once: only for this command

    figures = rig_bench(capture=args.capture, frames=args.frames, sample_frames=args.sample_frames, docs=args.docs,
                        repeat=args.repeat, reference=args.reference, long_only=args.long_only, say=progress_line,
                        overwrite=args.overwrite)
    print(json.dumps(figures, indent=2), file=console.stdout())
    return 0


def _cmd_convert(args):
    return convert_main(args.rest, parents=[OUTPUT_OPTIONS])


def _cmd_bench(args):
    if args.realism is not None:  # the cross-character benchmark (solvers/tools/synthetic/realism/): own options
        from ..solvers.tools.bench.realism_bench import main as realism_main  # scipy: loaded when it runs

        return realism_main(args.realism)
    if args.landmarks:  # renders a real face performing a recording, then retargets the footage (minutes)
        return landmark_bench_main(["--frames", args.frames if args.frames != "60" else "300"])
    if args.accuracy:  # accuracy distributions instead of timings (solvers/tools/bench/accuracy_bench.py)
        return accuracy_main(["--draws", args.draws, "--clips", args.clips, "--size", args.size, "--frames", args.frames])
    if args.memory:  # the memory case on its own (it takes minutes per take)
        for row in bench_memory((3600, 36000) if args.quick else MEMORY_FRAMES):
            print(row["line"], flush=True)
        return 0
    if args.clean:  # the cleaning case on its own
        for row in bench_clean((360, 3600) if args.quick else (3600, 36000)):
            print(_bench_line(row), flush=True)
        return 0
    if args.batch:  # minutes of its own: only when asked
        print(_bench_line(bench_batch(takes=args.batch_takes, jobs=args.batch_jobs, repeat=args.repeat)), flush=True)
        return 0
    frames = 3600 if args.quick else 36000
    for row in run_benchmarks(quick=args.quick):
        print(_bench_line(row), flush=True)
    for row in (bench_keying(frames=frames), *bench_cli_retarget(frames=frames)):  # a smaller character's take by stage
        print(_bench_line(row), flush=True)
    return 0


def _cmd_template(args):
    return template_main(args.rest, parents=[OUTPUT_OPTIONS])


def _cmd_build_extension(args):
    return build_extension_main(args.rest, parents=[OUTPUT_OPTIONS])


def _cmd_landmark_models(args):
    return landmark_models_main(args.rest, parents=[OUTPUT_OPTIONS])


def _bench_line(row):
    ratio = f"{row['ratio']:.3g}x vs {row['baseline_seconds']:.1f} s baseline" if row.get("ratio") else "no baseline"
    return f"{row['name']}: {row['seconds']:.3f} s median; {ratio}; {goal_verdict(row)}; {row['note']}"


def _overwrite_flag(parser):
    parser.add_argument("--overwrite", action="store_true",
                        help="let outputs replace existing files facecap did not write (default: refused; "
                             "facecap's own earlier outputs are always replaced)")


def version():
    """The extension's version, from ``blender_manifest.toml`` (in the zip as in the checkout)."""
    try:
        return tomllib.loads((ROOT / "blender_manifest.toml").read_text(encoding="utf-8")).get("version", "unknown")
    except (OSError, tomllib.TOMLDecodeError):
        return "unknown"


def _output_options():
    """-q/--quiet and -v/--verbose, accepted before or after the command (``facecap -q retarget`` and
    ``facecap retarget -q``): no default here, so a command's own parser does not overwrite the other's."""
    options = argparse.ArgumentParser(add_help=False)
    group = options.add_argument_group("output")
    group.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                       help="only warnings and errors on stderr (no progress lines)")
    group.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                       help="also debug lines on stderr, Blender's own output among them")
    return options


OUTPUT_OPTIONS = _output_options()



def build_parser():
    parser = argparse.ArgumentParser(
        prog="facecap", parents=[OUTPUT_OPTIONS],
        description="Performance-driven facial retargeting: markers, phone weights or video onto a character's "
                    "shape keys, headless. 'facecap COMMAND --help' describes a command.")
    parser.add_argument("--version", action="version", version=f"facecap {version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name, func, **kwargs):
        help_line, description = COMMANDS[name]
        forwarded = description is None  # the tool's own parser answers --help
        p = sub.add_parser(name, help=help_line, description=description, parents=[] if forwarded else [OUTPUT_OPTIONS],
                           add_help=not forwarded, **kwargs)
        if forwarded:
            p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(func=func)
        return p

    p = command("retarget", _cmd_retarget)
    p.add_argument("--config", required=True, help="take config (.toml)")
    p.add_argument("--replace", action="store_true",
                   help="start from [target] blend even when the output .blend exists (default: add the solve to it)")
    p.add_argument("--html", default=None, help="write the review page here (overrides [output] html)")
    p.add_argument("--truth", default=None, help="known weights CSV (frame,<shape>,...) the review page overlays")
    _overwrite_flag(p)
    p = command("batch", _cmd_batch)
    p.add_argument("takes", nargs="+", metavar="TAKES",
                   help="take configs, folders of them (and of take folders), or batch files (a [batch] table and "
                        "shared [defaults])")
    p.add_argument("--jobs", type=int, default=None, help="takes at once on this machine (default: its cores)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on a Dask cluster, e.g. tcp://farm:8786 (pip install 'facecap[farm]')")
    p.add_argument("--summary", default=None, metavar="PATH",
                   help="summary JSON (and .csv beside it); default ./facecap-batch.json")
    p.add_argument("--resume", action="store_true",
                   help="skip takes the summary records as done with the same inputs and config, outputs present")
    p.add_argument("--replace", action="store_true", help="as retarget --replace, for every take")
    _overwrite_flag(p)
    p = command("demo", _cmd_demo)
    p.add_argument("--out", default="facecap-demo", help="output folder (default: ./facecap-demo)")
    command("inspect", _cmd_inspect)
    command("convert", _cmd_convert)
    command("track", _cmd_track)
    p = command("tune", _cmd_tune)
    p.add_argument("--config", required=True, help="take config (.toml) with [tuning] corrections")
    _overwrite_flag(p)
    command("compare", _cmd_compare)
    command("config-docs", _cmd_config_docs)
    p = command("bench", _cmd_bench)
    p.add_argument("--quick", action="store_true", help="3,600 frames instead of 36,000")
    p.add_argument("--accuracy", action="store_true", help="accuracy over random scenarios instead (stabilisation, "
                   "solve, tracking, flow) side by side with plain references")
    p.add_argument("--realism", nargs=argparse.REMAINDER, metavar="OPTION",
                   help="the cross-character benchmark: a human face model performing real iPhone recordings, solved "
                        "onto other characters by every strategy and knowledge tier (docs/accuracy.md); its own "
                        "options follow it (--draws, --frames, --targets, --layouts, --methods, --real, --json; "
                        "`bench --realism --help`)")
    p.add_argument("--landmarks", action="store_true", help="face landmarks on rendered footage of the ICT face "
                   "performing a Live Link Face recording, retargeted onto another identity and the sample character")
    p.add_argument("--draws", default="30", help="--accuracy: random marker takes (default 30)")
    p.add_argument("--clips", default="3", help="--accuracy: clips per footage kind (default 3)")
    p.add_argument("--size", default="640x480", help="--accuracy: footage resolution (default 640x480)")
    p.add_argument("--frames", default="60", help="--accuracy: frames per clip (default 60)")
    p.add_argument("--batch", action="store_true",
                   help="only the batch case: batch --jobs N against sequential retarget runs (minutes)")
    p.add_argument("--batch-takes", type=int, default=20, help="takes of 720 frames in the batch case (default 20)")
    p.add_argument("--batch-jobs", type=int, default=2, help="--jobs of the batch case (default 2)")
    p.add_argument("--repeat", type=int, default=3, help="runs of the batch case, median (default 3)")
    p.add_argument("--clean", action="store_true",
                   help="only the cleaning case: spike removal and spline gap fill on 3,600 and 36,000 frames with "
                        "5%% spikes, against one spline per gap")
    p.add_argument("--memory", action="store_true",
                   help="only the memory case: peak memory of `retarget`'s process tree on 36,000- and 360,000-frame "
                        "takes (with --quick 3,600 and 36,000); about 20 minutes")
    p = command("rig-bench", _cmd_rig_bench)
    p.add_argument("--capture", type=Path, help="a real capture solved onto the Rigify face and the shape keys "
                   "(e.g. c3dorg_29_Facial-Sing.c3d, bound by position)")
    p.add_argument("--frames", type=int, default=3600, help="frames of the long Rigify take (default 3600)")
    p.add_argument("--sample-frames", type=int, default=600, help="frames of the control-rig takes (default 600)")
    p.add_argument("--docs", type=Path, help="also render the Rigify face from the capture to DIR/rigify_face.png")
    p.add_argument("--repeat", type=int, default=1, help="solve the long Rigify take N times: median times (default 1)")
    p.add_argument("--reference", action="store_true", help="also the slow reference path: speed-up, both accuracies")
    p.add_argument("--long-only", action="store_true", help="only the long Rigify take (no control rigs, no capture)")
    _overwrite_flag(p)
    p = command("docs-images", _cmd_docs_images)
    p.add_argument("--out", default=None, help="output folder (default: docs/images of this checkout)")
    p.add_argument("--size", type=int, default=280, help="tile height in pixels (default: 280)")
    p.add_argument("--engine", choices=("workbench", "cycles"), default="workbench",
                   help="Workbench (OpenGL, software via Mesa EGL without a GPU) or Cycles on the CPU")
    p.add_argument("--solved", default=None, help="solved weights CSV of the sample take (default: retarget it)")
    p.add_argument("--pictures", help="which, comma-separated: expressions,markers,contact_sheet,rom (default: all)")
    _overwrite_flag(p)
    command("template", _cmd_template)
    command("build-extension", _cmd_build_extension)
    command("landmark-models", _cmd_landmark_models)
    return parser


def main(argv=None):
    """Entry point; returns the process exit status."""

    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["batch-worker"]:
        return _batch_worker(argv[1:])
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    args.argv = argv[1:]
    if extra:
        if args.command not in FORWARDING:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        args.rest = extra + list(args.rest)
    if args.command in FORWARDING:  # -q / -v given before the command reach the tool too
        args.rest = [flag for flag, on in (("--quiet", getattr(args, "quiet", False)),
                                           ("--verbose", getattr(args, "verbose", False))) if on] + list(args.rest)
    console.configure(console.verbosity(args) if args.command not in FORWARDING else _forwarded_verbosity(args.rest))
    if args.command in BATCH_COMMANDS:
        keep_freed_memory()
    previous = console.interrupts_handled()  # Ctrl-C and SIGTERM: KeyboardInterrupt at any moment
    try:
        with console.closed_pipe_ends_quietly():
            if args.command in BLENDER_COMMANDS:
                with console.blender_output_captured():
                    return args.func(args)
            return args.func(args)
    except FacecapError as exc:
        if isinstance(exc, Cancelled):  # Ctrl-C during a video take's flow: nothing was written (not an error)
            print(f"facecap: {exc}; nothing written", file=sys.stderr)
            return 130
        return console.failed(exc)
    except KeyboardInterrupt:
        print("facecap: interrupted; outputs not finished were not written", file=sys.stderr)
        return 130
    except Exception as exc:  # the system refused something, or a bug: one line all the same
        if os.environ.get("FACECAP_TRACEBACK") and not isinstance(exc, (OSError, MemoryError)):
            raise
        return console.failed(exc)
    finally:
        console.restore_handlers(previous)


def _forwarded_verbosity(rest):
    quiet = any(a in ("-q", "--quiet") for a in rest)
    return -1 if quiet else 1 if any(a in ("-v", "--verbose") for a in rest) else 0


def keep_freed_memory():
    """Ask glibc's allocator to keep freed memory in the process for reuse instead of returning it
    to the system (mmap threshold 32 MB, trim threshold 1 GB, top pad 64 MB). A take's solve
    allocates and frees arrays of tens of MB over and over; returned memory comes back as fresh
    pages, each one a page fault when first written (measured on the 36,000-frame CLI take: 1.1
    million faults, 5-8 s of system CPU; with this 0.67-0.81 million, 3.7-5.3 s; peak memory +3 %).
    For one-shot batch processes only: a Blender session should give memory back. Elsewhere (no
    glibc) it does nothing. Returns whether the settings were taken."""

    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3  # from malloc.h
    settings = ((m_mmap_threshold, 32 << 20), (m_trim_threshold, 1 << 30), (m_top_pad, 64 << 20))
    return all([bool(mallopt(option, value)) for option, value in settings])  # a list: every setting is applied
