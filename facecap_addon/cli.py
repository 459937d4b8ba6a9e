"""Headless command line, shared by ``python -m facecap`` and ``blender -b -P facecap_addon/cli.py -- ...``.

Commands
--------
retarget --config take.toml   solve a take onto its character with its [solve] strategy and write
                              .blend / weights CSV / report (/ the actor basis, [output] actor_basis);
                              a [source] video take solves from flow-PCA features (Ctrl-C cancels);
                              --html PATH [--truth CSV]: the review page (docs/review.md)
compare [options]             measure every strategy on the same synthetic takes (Markdown table)
demo [--out DIR]              retarget the bundled sample take and print its accuracy against ground truth
inspect FILE [options]        describe a capture file (--json: as JSON); non-zero exit with a one-line reason if it is bad
convert IN OUT [options]      a capture file in another format (.csv .c3d .trc .json; weights to a weights CSV)
track --config take.toml      track video footage (LK points or dense flow) and write the 2D tracks CSV
tune --config take.toml       retune what the strategy learned from [tuning] corrections, store the new
                              library version ([tuning] out) and write the re-solved take
batch TAKES... [--jobs N]     run many takes (configs, folders, batch files with [defaults]), each isolated,
  [--scheduler ADDRESS]       on worker processes here or on a Dask farm; JSON / CSV summary; --resume
  [--summary PATH] [--resume] skips takes whose inputs, config and outputs are unchanged (docs/batch.md)
bench [--quick] [--accuracy] [--batch] [--memory]
                              time the solve, the keying and the whole CLI, with ratios to naive baselines;
                              --accuracy: accuracy over random scenarios; --batch: batch --jobs 2 against
                              sequential retarget runs; --memory: peak memory of the CLI's process tree on
                              long takes
docs-images [--out DIR]       render the documentation's pictures (docs/images) from the sample character
build-extension [--out DIR]   build and validate the Blender extension zips, one per platform, with the
                              locked scipy/OpenCV wheels (docs/install.md)

Every expected failure (bad config, missing or malformed file, a full disk) exits with status 1 and one
line on stderr per problem naming the file and field; Ctrl-C and SIGTERM exit with 130 at any moment; a bug
is one line too ("internal error", its traceback with FACECAP_TRACEBACK=1). Outputs go through one output
policy (``solvers/io/outputs.py``; ``--overwrite`` lets them replace files facecap did not write).
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
import ctypes  # noqa: E402
import os  # noqa: E402
import signal  # noqa: E402
import threading  # noqa: E402

import numpy as np  # noqa: E402

from ..solvers.config import load_take_config  # noqa: E402
from ..solvers.errors import FacecapError  # noqa: E402
from ..solvers.tools import config_docs  # noqa: E402
from ..solvers.tools.accuracy_bench import main as accuracy_main  # noqa: E402
from ..solvers.tools.bench import run_benchmarks  # noqa: E402
from ..solvers.tools.build_extension import main as build_extension_main  # noqa: E402
from ..solvers.tools.clean_bench import bench_clean  # noqa: E402
from ..solvers.tools.convert import main as convert_main  # noqa: E402
from ..solvers.tools.inspect import main as inspect_main  # noqa: E402
from ..solvers.video.cli import main as track_main  # noqa: E402
from ..solvers.video.reading import Cancelled  # noqa: E402
from .batch import run_batch  # noqa: E402
from .batch_worker import serve  # noqa: E402
from .bench import MEMORY_FRAMES, bench_batch, bench_cli_retarget, bench_keying, bench_memory  # noqa: E402
from .demo import run_demo  # noqa: E402
from .headless import progress_line, run_take  # noqa: E402
from .review import review_flags  # noqa: E402


def _cmd_retarget(args):
    config = review_flags(load_take_config(args.config), args.html, args.truth)
    result, outputs = run_take(config, replace=args.replace, overwrite=args.overwrite)

    ok = np.isfinite(result.residual_rms)
    residual = (f"mean residual {np.mean(result.residual_rms[ok]) * 1e3:.3f} mm ({result.residual_space} space)"
                if ok.any() else "no marker residual for this strategy")
    print(f"retargeted {result.frames.size} frames, {len(result.shape_names)} shapes (strategy: {result.strategy}); {residual}")
    for key, value in outputs.items():
        print(f"  {key}: {value}")
    return 0


def _cmd_batch(args):
    return run_batch(args)


def _cmd_batch_worker(args):
    fd_in, fd_out = (int(v) for v in args.fds.split(","))
    return serve(fd_in, fd_out)


def _cmd_demo(args):
    return run_demo(Path(args.out))


def _cmd_inspect(args):
    return inspect_main(args.rest)


def _cmd_compare(args):
    from ..solvers.tools.compare import main as compare_main  # loads scipy

    return compare_main(args.rest)


def _cmd_config_docs(args):
    return config_docs.main(args.rest)


def _cmd_track(args):
    return track_main(args.rest)


def _cmd_tune(args):
    config = load_take_config(args.config)
    result, outputs = run_take(config, tune=True, overwrite=args.overwrite)
    tuned = result.retune
    v = tuned.version
    print(f"retuned '{result.strategy}' from {len(tuned.frames)} corrected frame(s): corrected RMSE "
          f"{tuned.corrected_rmse_before:.4f} -> {tuned.corrected_rmse_after:.4f}; other frames moved "
          f"{tuned.others_moved:.1%}")
    print(f"  new version: {v.name} (parent {v.parent})" if tuned.changed else
          f"  library unchanged ({v.name}); no new version written")
    for note in tuned.notes:
        print(f"  note: {note}")
    for key, value in outputs.items():
        print(f"  {key}: {value}")
    return 0


def _cmd_docs_images(args):
    from .docs_images import render_docs_images  # imports bpy (and bmesh) at once: only for this command

    written = render_docs_images(args.solved, args.out, size=args.size, engine=args.engine, say=progress_line)
    for name, path in written.items():
        print(f"  {name}: {path} ({path.stat().st_size / 1024:.0f} KB)")
    return 0


def _cmd_convert(args):
    return convert_main(args.rest)


def _cmd_bench(args):
    if args.accuracy:  # accuracy distributions instead of timings (solvers/tools/accuracy_bench.py)
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
    print(_bench_line(bench_keying(frames=frames)), flush=True)
    print(_bench_line(bench_cli_retarget(frames=frames)), flush=True)
    return 0


def _cmd_build_extension(args):
    return build_extension_main(args.rest)


def _bench_line(row):
    ratio = f"{row['ratio']:.0f}x vs {row['baseline_seconds']:.1f} s baseline" if row.get("ratio") else "no baseline"
    return f"{row['name']}: {row['seconds']:.3f} s median; {ratio}; goal {row['goal']}; {row['note']}"


def _overwrite_flag(parser):
    parser.add_argument("--overwrite", action="store_true",
                        help="let outputs replace existing files facecap did not write (default: refused; "
                             "facecap's own earlier outputs are always replaced)")


def build_parser():
    parser = argparse.ArgumentParser(prog="facecap", description="Performance-driven facial retargeting.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("retarget", help="retarget a take described by a TOML config")
    p.add_argument("--config", required=True, help="take config (.toml)")
    p.add_argument("--replace", action="store_true",
                   help="start from [target] blend even when the output .blend exists (default: add the solve to it)")
    p.add_argument("--html", default=None, help="write the review page here (overrides [output] html)")
    p.add_argument("--truth", default=None, help="known weights CSV (frame,<shape>,...) the review page overlays")
    _overwrite_flag(p)
    p.set_defaults(func=_cmd_retarget)
    p = sub.add_parser("batch", help="run many takes, each isolated, here (--jobs) or on a Dask farm (--scheduler)")
    p.add_argument("takes", nargs="+", metavar="TAKES",
                   help="take configs, folders of them, or batch files (a [batch] table and shared [defaults])")
    p.add_argument("--jobs", type=int, default=None, help="takes at once on this machine (default: its cores)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on a Dask cluster, e.g. tcp://farm:8786 (pip install 'facecap[farm]')")
    p.add_argument("--summary", default=None, metavar="PATH",
                   help="summary JSON (and .csv beside it); default ./facecap-batch.json")
    p.add_argument("--resume", action="store_true",
                   help="skip takes the summary records as done with the same inputs and config, outputs present")
    p.add_argument("--replace", action="store_true", help="as retarget --replace, for every take")
    _overwrite_flag(p)
    p.set_defaults(func=_cmd_batch)
    p = sub.add_parser("batch-worker")  # started by batch, not by hand: no help line
    p.add_argument("--fds", required=True)
    p.set_defaults(func=_cmd_batch_worker)
    p = sub.add_parser("demo", help="retarget the bundled sample take and print its accuracy")
    p.add_argument("--out", default="facecap-demo", help="output folder (default: ./facecap-demo)")
    p.set_defaults(func=_cmd_demo)
    p = sub.add_parser("inspect", help="describe a marker or weights file (markers, frames, rate, units, gaps, segments)",
                       add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_inspect)
    p = sub.add_parser("convert", help="convert a capture to CSV, C3D, TRC or JSON (weights: to a weights CSV)",
                       add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_convert)
    p = sub.add_parser("compare", help="accuracy and time of every strategy on the same synthetic takes (Markdown)",
                       add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_compare)
    p = sub.add_parser("track", help="track markers or dense flow in video footage and write 2D tracks", add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_track)
    p = sub.add_parser("tune", help="retune the strategy from an animator's corrected frames and re-solve the take")
    p.add_argument("--config", required=True, help="take config (.toml) with [tuning] corrections")
    _overwrite_flag(p)
    p.set_defaults(func=_cmd_tune)
    p = sub.add_parser("config-docs", help="write the take-config reference (docs/config.md) from the option table",
                       add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_config_docs)
    p = sub.add_parser("bench", help="time the solver, keying and the whole CLI against naive baselines")
    p.add_argument("--quick", action="store_true", help="3,600 frames instead of 36,000")
    p.add_argument("--accuracy", action="store_true", help="accuracy over random scenarios instead (stabilisation, "
                   "solve, tracking, flow) side by side with plain references")
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
    p.set_defaults(func=_cmd_bench)
    p = sub.add_parser("docs-images", help="render the documentation's pictures from the sample character")
    p.add_argument("--out", default=None, help="output folder (default: docs/images of this checkout)")
    p.add_argument("--size", type=int, default=280, help="tile height in pixels (default: 280)")
    p.add_argument("--engine", choices=("workbench", "cycles"), default="workbench",
                   help="Workbench (OpenGL, software via Mesa EGL without a GPU) or Cycles on the CPU")
    p.add_argument("--solved", default=None, help="solved weights CSV of the sample take (default: retarget it)")
    p.set_defaults(func=_cmd_docs_images)
    p = sub.add_parser("build-extension", help="build the Blender extension zips (one per platform, wheels bundled)",
                       add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=_cmd_build_extension)
    return parser


def main(argv=None):
    """Entry point; returns the process exit status."""

    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)[1:]
    if extra:
        if args.command not in FORWARDING:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        args.rest = extra + list(args.rest)
    if args.command in BATCH_COMMANDS:
        keep_freed_memory()
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _interrupt) if main_thread else None  # cleans up as Ctrl-C does
    try:
        return args.func(args)
    except FacecapError as exc:
        if isinstance(exc, Cancelled):  # Ctrl-C during a video take's flow: nothing was written
            print(f"facecap: {exc}; nothing written", file=sys.stderr)
            return 130
        for line in str(exc).splitlines():  # a config's problems: one line each
            print(f"facecap: error: {line}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("facecap: interrupted; outputs not finished were not written", file=sys.stderr)
        return 130
    except OSError as exc:  # the system refused something the checks could not foresee
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"facecap: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except MemoryError:
        print("facecap: error: out of memory (the take is too large for this machine's memory)", file=sys.stderr)
        return 1
    except Exception as exc:  # a bug: one line, the traceback on request
        if os.environ.get("FACECAP_TRACEBACK"):
            raise
        text = " ".join(str(exc).split())[:300]
        print(f"facecap: internal error (a bug in facecap; run with FACECAP_TRACEBACK=1 for where): "
              f"{type(exc).__name__}: {text}", file=sys.stderr)
        return 1
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)


def _interrupt(signum, frame):
    raise KeyboardInterrupt


#: Commands that pass their own options on to their tool
FORWARDING = ("compare", "track", "inspect", "convert", "config-docs", "build-extension")

#: Commands that run one take through and exit: they keep freed memory for reuse (``keep_freed_memory``).
BATCH_COMMANDS = ("retarget", "tune", "demo", "batch-worker")


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
