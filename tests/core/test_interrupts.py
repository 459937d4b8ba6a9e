"""Ctrl-C where Python cannot pass it on: a signal that arrives while a weakref callback runs (the import
system's module locks use them, and the CLI imports numpy, scipy and Blender) raises KeyboardInterrupt inside
that callback, which Python prints as "Exception ignored in ..." and forgets. The command line's hook delivers
it again (``console.lost_interrupts_redelivered``)."""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import gc, signal, sys, time, weakref
    from facecap.facecap_addon.headless import console

    signal.signal(signal.SIGINT, signal.default_int_handler)  # Python's own, even when started with SIGINT ignored
    if sys.argv[1] == "hooked":
        console.interrupts_handled()

    class Thing:
        pass

    def callback(ref):  # as importlib's module-lock callback: the signal's handler runs inside it
        signal.raise_signal(signal.SIGINT)

    thing = Thing()
    ref = weakref.ref(thing, callback)
    try:
        del thing
        gc.collect()
        deadline = time.monotonic() + 3  # the redelivery comes within 0.05 s
        while time.monotonic() < deadline:
            time.sleep(0.01)
        print("ran on")
    except KeyboardInterrupt:
        print("interrupted")
""")


def run(mode):
    return subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, timeout=60)


def test_python_alone_loses_an_interrupt_raised_in_a_weakref_callback():
    """What the hook is for (if Python ever passes it on itself, the hook is no longer needed)."""
    proc = run("bare")
    assert proc.stdout.strip() == "ran on" and "Exception ignored" in proc.stderr, (proc.stdout, proc.stderr)


def test_the_command_lines_handling_delivers_it_again_and_prints_nothing():
    proc = run("hooked")
    assert proc.stdout.strip() == "interrupted", (proc.stdout, proc.stderr)
    assert proc.stderr == "", proc.stderr


def test_the_hook_leaves_other_unraisable_exceptions_to_python():
    code = ("import gc, weakref\n"
            "from facecap.facecap_addon.headless import console\n"
            "console.lost_interrupts_redelivered()\n"
            "class T:\n    def __del__(self):\n        raise ValueError('in a finaliser')\n"
            "t = T(); del t; gc.collect(); print('done')")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == "done" and "ValueError: in a finaliser" in proc.stderr, proc.stderr


def test_the_temporary_folder_is_probed_before_ctrl_c_can_interrupt_the_probe(tmp_path):
    """Python finds its temporary folder once, by writing and removing a probe file there; a Ctrl-C between the two
    (the .blend opening, where facecap first asks for a temporary file) left the probe in $TMPDIR in 1-3 runs of 10
    of tests/e2e/test_reliability3_cli.py's test 10. Signal handling set up, the folder is known and nothing is left
    there."""
    script = textwrap.dedent("""
        import os, tempfile
        from facecap.facecap_addon.headless import console
        assert tempfile.tempdir is None
        console.interrupts_handled()
        print(tempfile.tempdir == os.environ["TMPDIR"], os.listdir(os.environ["TMPDIR"]))
    """)
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 0, done.stderr[-800:]
    assert done.stdout.split() == ["True", "[]"]
