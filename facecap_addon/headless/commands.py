"""The commands of ``python -m facecap`` (and of ``blender -b -P <extension>/facecap_addon/cli.py -- ...``):
what each does, its one-line summary and the description its ``--help`` starts with, and which of them
forward their options, start Blender or run one take (``facecap_addon/cli.py`` parses and dispatches).

Commands
--------
retarget --config take.toml   solve a take onto its character with its [solve] strategy and write
                              .blend / weights CSV / report (/ the actor basis, [output] actor_basis);
                              a [source] video take solves from flow-PCA features (Ctrl-C cancels);
                              --html PATH [--truth CSV]: the review page (docs/review.md)
compare [options]             measure every strategy on the same synthetic takes (Markdown table)
demo [--out DIR]              retarget the bundled sample take and print its accuracy against ground truth
inspect FILE [options]        describe a capture file (--json: as JSON); non-zero exit with a one-line reason if it is bad
convert IN OUT [options]      convert a capture file to another format (.csv .c3d .trc .json; weights to a
                              weights CSV)
track --config take.toml      track video footage (LK points or dense flow) and write the 2D tracks CSV
tune --config take.toml       retune what the strategy learned from [tuning] corrections, store the new
                              library version ([tuning] out) and write the re-solved take
batch TAKES... [--jobs N]     run many takes (configs, folders, batch files with [defaults]), each isolated,
  [--scheduler ADDRESS]       on worker processes here or on a Dask farm; JSON / CSV summary; --resume
  [--summary PATH] [--resume] skips takes whose inputs, config and outputs are unchanged (docs/batch.md)
bench [--quick] [--accuracy] [--batch] [--memory] [--landmarks] [--clean]
                              time the solve, the keying and the whole CLI, with ratios to naive baselines;
                              --accuracy: accuracy over random scenarios; --batch: batch --jobs 2 against
                              sequential retarget runs; --memory: peak memory of the CLI's process tree on
                              long takes; --landmarks: face landmarks on rendered footage of a real face;
                              --clean: spike removal and gap filling on long takes
config-docs [--out PATH] [--commands PATH]
                              write docs/config.md and docs/commands.md from the code
docs-images [--out DIR]       render the documentation's pictures (docs/images) from the sample character
template fetch | convert PATH install the optional human template: download ICT-FaceKit, or convert a download
                              (zip or folder); hash-checked; `template info`: where it is (docs/strategies.md)
rig-bench [--capture FILE]    the test rigs' figures (control, mixed bone/slider, Rigify face and human rigs)
build-extension [--out DIR]   build and validate the Blender extension zips, one per Blender generation
                              and platform, with the locked scipy/OpenCV wheels (docs/install.md)
landmark-models [fetch|info]  put MediaPipe's face-mesh models (from the locked mediapipe wheel) into the
                              facecap cache; fetch: the Face Landmarker bundle (blendshapes, hash-checked)

Every command takes -q/--quiet (only warnings and errors on stderr) and -v/--verbose (debug lines too,
Blender's own output among them); ``facecap --version``. Progress and warnings go to stderr through
logging (``console.py``), a command's product to stdout. Every expected failure (bad config, missing or
malformed file, a full disk) exits with status 1 and one line on stderr per problem naming the file and
field; Ctrl-C and SIGTERM exit with 130 at any moment; a bug is one line too ("internal error", its
traceback with FACECAP_TRACEBACK=1). Outputs go through one output policy (``solvers/io/outputs.py``;
``--overwrite`` lets them replace files facecap did not write).
"""

#: command: (one line for the command list, the description its --help starts with)
COMMANDS = {
    "retarget": ("retarget a take described by a TOML config",
                 "Retarget a take described by a TOML config onto its character and write the .blend, the weights "
                 "CSV, the JSON report and the review page its [output] names."),
    "batch": ("run many takes, each isolated, here (--jobs) or on a Dask farm (--scheduler)",
              "Run many takes, each in its own worker process, here or on a Dask farm, and write a summary "
              "(JSON, CSV and an index of the review pages)."),
    "demo": ("retarget the bundled sample take and print its accuracy",
             "Retarget the bundled sample take onto the bundled sample character and print the accuracy against "
             "the ground truth and the files written."),
    "inspect": ("describe a marker or weights file (markers, frames, rate, units, gaps, segments)", None),
    "convert": ("convert a capture to CSV, C3D, TRC or JSON (weights: to a weights CSV)", None),
    "track": ("track markers or dense flow in video footage and write 2D tracks", None),
    "tune": ("retune the strategy from an animator's corrected frames and re-solve the take",
             "Retune what the strategy learned from an animator's corrected frames ([tuning] corrections), store "
             "the new library version and write the re-solved take."),
    "compare": ("accuracy and time of every strategy on the same synthetic takes (Markdown)", None),
    "config-docs": ("write the config reference (docs/config.md) from the option tables", None),
    "bench": ("time the solver, keying and the whole CLI against naive baselines",
              "Time the solver, the keying and the whole command line against naive baselines, and print each "
              "with its ratio and goal."),
    "docs-images": ("render the documentation's pictures from the sample character",
                    "Render the documentation's pictures (docs/images) from the sample character, headless."),
    "rig-bench": ("the test rigs' figures (control, mixed bone/slider, Rigify face and human rigs)",
                  "Solve the test rigs (a control rig with correctives, a rig mixing bones and sliders, a Rigify face, "
                  "the whole Rigify human) from known control curves and a real capture; print their figures as JSON."),
    "template": ("install the optional human template (download ICT-FaceKit or convert a copy); where it is", None),
    "build-extension": ("build the Blender extension zips (per Blender generation and platform)", None),
    "landmark-models": ("put the face-landmark models into the facecap cache; fetch: the Face Landmarker bundle",
                        None),
}


#: Commands that pass their own options on to their tool
FORWARDING = ("compare", "track", "inspect", "convert", "config-docs", "build-extension", "template",
              "landmark-models")

#: Commands that run one take through and exit: they keep freed memory for reuse (``keep_freed_memory``).
BATCH_COMMANDS = ("retarget", "tune", "demo")
#: Commands that start Blender: its own output lines are captured (``console.blender_output_captured``).
BLENDER_COMMANDS = ("retarget", "tune", "demo", "docs-images")
