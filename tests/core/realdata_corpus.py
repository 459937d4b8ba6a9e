"""facecap's readers on the real capture corpus, compared file by file with reference readers.

The corpus is ``shared/data/realdata`` beside the checkout (``tests/shared_data.py``) (C3D, TRC and Live Link Face files from 15+ vendors,
``SOURCES.md`` there). References: ezc3d and py-c3d (``c3d`` on PyPI, both in the ``test`` extra)
for C3D, a plain ``csv``-module parse of the rows for TRC, ``np.interp`` of the raw rows for Live
Link Face. ``test_realdata.py`` asserts every outcome; this module also writes the table of
``docs/realdata.md``::

    python tests/core/realdata_corpus.py --write docs/realdata.md

The reference readers run in a child process (``--references``): ezc3d is C++ and may crash on a
malformed file, which must not take the test run with it.
"""

import argparse
import csv
import json
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: shared_data, also when run as a script
from shared_data import REALDATA as CORPUS  # noqa: E402
#: Seconds a reference reader may take on one file before it counts as failing (ezc3d needs ~20 s to
#: give up on two files it cannot read; the others take under 1 s on a quiet machine).
REFERENCE_SECONDS = 15.0
#: Relative difference allowed for "float32": py-c3d scales integer files in float32.
FLOAT32 = 2e-7
#: Vendors for files without a MANUFACTURER group, from their source (SOURCES.md, c3d.org readmes).
NAME_VENDORS = {
    "codamotion": "Codamotion", "phasespace": "PhaseSpace", "BKIN": "BKIN Technologies",
    "MotionMonitor": "Innovative Sports Training (The MotionMonitor)", "kyowadengyo": "Kyowa Dengyo",
    "Facial-Sing": "NaturalPoint", "evart": "Motion Analysis (EVaRT)", "BTS": "BTS", "Optotrak": "NDI (Optotrak)",
    "Kistler": "Kistler", "Qualisys": "Qualisys", "Vicon": "Vicon", "opensim": "OpenSim (Motion Analysis TRC)",
    "btk_": "BTK sample", "llf_": "Epic Games (Live Link Face)",
}


@dataclass
class Outcome:
    """One corpus file: what facecap read and how it compares."""

    file: str
    kind: str
    vendor: str
    frames: int
    markers: int
    result: str      # "read", "read (warning)" or "refused"
    agreement: str   # "ezc3d: exact", "py-c3d: float32 ...", "header ...", "rows: exact", ...
    notes: tuple
    reason: str = ""  # the refusal message


# --------------------------------------------------------------------------------------------
# reference readings (child process)


def _ezc3d(path):
    import ezc3d

    c = ezc3d.c3d(str(path))
    return np.transpose(c["data"]["points"][:3], (2, 1, 0)).astype(np.float64)


def _pyc3d(path):
    import c3d

    with open(path, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3d.Reader(fh)
        frames = [points for _, points, _ in reader.read_frames()]
    a = np.asarray(frames, dtype=np.float64)
    pos = a[:, :, :3].copy()
    pos[a[:, :, 3] < 0] = np.nan
    return pos


def dump_references(files, out):
    """Write ``<out>/<file>.<ref>.npy`` (or ``.err`` with the message) for every file and reference."""
    out = Path(out)
    for path in files:
        for ref, read in (("ezc3d", _ezc3d), ("py-c3d", _pyc3d)):
            if (out / f"{path.name}.{ref}.npy").exists() or (out / f"{path.name}.{ref}.err").exists():
                continue  # read by an earlier child
            (out / f"{path.name}.{ref}.start").write_text("")  # a crash leaves this behind
            try:
                np.save(out / f"{path.name}.{ref}.npy", read(path))
            except Exception as exc:  # noqa: BLE001 - any failure of a reference is recorded
                (out / f"{path.name}.{ref}.err").write_text(f"{type(exc).__name__}: {exc}"[:200])
            (out / f"{path.name}.{ref}.start").unlink()


def reference_readings(files):
    """{file name: {ref: positions (F, M, 3) or an error string}}, read in child processes."""
    files = list(files)
    refs = ("ezc3d", "py-c3d")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        have = lambda p, r: (tmp / f"{p.name}.{r}.npy").exists() or (tmp / f"{p.name}.{r}.err").exists()  # noqa: E731
        todo = files
        while todo:
            child = subprocess.Popen([sys.executable, __file__, "--references", str(tmp), *map(str, todo)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            why = "crashed the process"
            while child.poll() is None:
                time.sleep(0.05)
                if any(time.time() - started > REFERENCE_SECONDS for started in _start_times(tmp)):
                    child.kill()  # ezc3d takes ~20 s to give up on some files it cannot read
                    child.wait()
                    why = f"gave up after {REFERENCE_SECONDS:g} s"
            for started in tmp.glob("*.start"):  # the child crashed or was stopped reading this one
                started.with_suffix(".err").write_text(f"the reader {why}")
                started.unlink()
            todo = [p for p in todo if not all(have(p, r) for r in refs)]
        return {p.name: {r: np.load(tmp / f"{p.name}.{r}.npy") if (tmp / f"{p.name}.{r}.npy").exists()
                         else (tmp / f"{p.name}.{r}.err").read_text() for r in refs} for p in files}


def _start_times(tmp):
    """Modification times of the ``.start`` markers (one may vanish while we look: the child finished it)."""
    out = []
    for started in tmp.glob("*.start"):
        try:
            out.append(started.stat().st_mtime)
        except FileNotFoundError:
            pass
    return out


# --------------------------------------------------------------------------------------------
# comparisons


def compare(ours, ref):
    """'exact', 'float32 (max <d>)' or a reason they differ, for two (F, M, 3) arrays."""
    if isinstance(ref, str):  # the reason (an exception, a crash, a timeout) depends on the machine's load: not shown
        return "cannot read it"
    if ref.shape != ours.shape:
        return f"reads {ref.shape[0]} frames x {ref.shape[1]} points"
    gap_a, gap_b = np.isnan(ours), np.isnan(ref)
    if (gap_a != gap_b).any():
        return f"differs ({int((gap_a != gap_b).any(axis=2).sum())} samples gap in one only)"
    both = ~gap_a
    if not both.any() or np.array_equal(ours[both], ref[both]):
        return "exact"
    diff = np.abs(ours[both] - ref[both])
    rel = diff / np.maximum(np.abs(ref[both]), 1e-30)
    if rel.max() <= FLOAT32:
        return f"float32 rounding (max {diff.max():.2g})"
    return f"differs (max {diff.max():.3g})"


def c3d_header(path):
    """(points, frames) that a C3D file's 512-byte header declares."""
    head = Path(path).read_bytes()[:512]
    endian = ">" if len(head) > 4 and _processor(path) == 86 else "<"
    words = np.frombuffer(head[:12], dtype=endian + "u2")
    return int(words[1]), int(words[4]) - int(words[3]) + 1


def _processor(path):
    data = Path(path).read_bytes()
    block = data[0]
    return data[(block - 1) * 512 + 3] if len(data) > (block - 1) * 512 + 3 else 0


def plausible(positions):
    """Median frame-to-frame step over the median marker extent (a misread layout gives noise, ~1)."""
    if positions.shape[0] < 2 or not np.isfinite(positions).any():
        return 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        step = np.nanmedian(np.linalg.norm(np.diff(positions, axis=0), axis=2))
        extent = np.nanmedian(np.nanmax(positions, axis=0) - np.nanmin(positions, axis=0))
    return float(step / extent) if extent > 0 and np.isfinite(step) else 0.0


def vendor_of(path):
    vendor = ""
    if path.suffix.lower() == ".c3d":
        text = path.read_bytes()
        at = text.find(b"COMPANY", 512)  # MANUFACTURER:COMPANY, from the raw bytes (no facecap internals)
        while 0 < at < 512 * 64 and not vendor:
            if text[at - 2] == 7:  # the name's length byte: COMPANY itself, not FILE_EXPORT_COMPANY
                vendor = _param_string(text, at, 7)
            at = text.find(b"COMPANY", at + 1)
    if not vendor:
        vendor = next((v for k, v in NAME_VENDORS.items() if k in path.name), "")
    if not vendor and path.name.startswith("c3dorg_"):
        vendor = f"c3d.org sample {path.name.split('_')[1]}"
    return vendor or "unknown"


def _param_string(data, at, name_len):
    """The string value of the character parameter whose name starts at ``at``."""
    body = at + name_len + 2
    try:
        etype, ndim = int.from_bytes(data[body:body + 1], "little", signed=True), data[body + 1]
        if etype != -1 or ndim < 1:
            return ""
        dims = list(data[body + 2:body + 2 + ndim])
        start = body + 2 + ndim
        return data[start:start + dims[0]].decode("latin-1").strip()
    except (IndexError, UnicodeDecodeError):
        return ""


# --------------------------------------------------------------------------------------------
# outcomes


def _read(path):
    from facecap.solvers.errors import FacecapError
    from facecap.solvers.io import import_markers

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = import_markers(path, units="mm")  # numbers as the file holds them
        # "mm" is given only to keep the numbers: the note that it overrides the file's units is not the file's
        notes = tuple(n for n in result.notes if not n.startswith("warning: the file says its units are"))
        return result.markers, notes, ""
    except FacecapError as exc:
        return None, (), str(exc).replace(str(path), path.name)


def c3d_outcomes(files=None):
    files = sorted((CORPUS / "c3d").iterdir()) if files is None else list(files)
    refs = reference_readings(files)
    out = []
    for path in files:
        markers, notes, reason = _read(path)
        vendor = vendor_of(path) if path.stat().st_size else "unknown"
        if markers is None:
            out.append(Outcome(path.name, "c3d", vendor, 0, 0, "refused", "", notes, reason))
            continue
        pos = markers.positions
        agreement = ""
        said = []
        for ref in ("ezc3d", "py-c3d"):
            verdict = compare(pos, refs[path.name][ref])
            if verdict == "exact" or verdict.startswith("float32"):
                agreement = f"{ref}: {verdict}"
                break
            said.append(f"{ref} {verdict}")
        if not agreement:
            points, frames = c3d_header(path)
            ok = (points, frames) == (markers.n_markers, markers.n_frames) and plausible(pos) < 0.5
            agreement = ("header: " if ok else "NONE: ") + f"{points} points, {frames} frames; " + "; ".join(said)
        result = "read (warning)" if any(n.startswith("warning:") for n in notes) else "read"
        out.append(Outcome(path.name, "c3d", vendor, markers.n_frames, markers.n_markers, result, agreement, notes))
    return out


def trc_rows(path):
    """A TRC file's coordinates by a plain tab (or, for a comma-separated file, comma) split: (F, M, 3),
    NaN for empty cells and for samples written as 0, 0, 0 (a missing marker, as OpenSim writes it); M =
    the named markers of line 4 or, when the rows hold more, as many as they hold."""
    with open(path, newline="", encoding="utf-8") as fh:
        first = fh.readline()
        fh.seek(0)
        rows = list(csv.reader(fh, delimiter="," if "\t" not in first and "," in first else "\t"))
    named = sum(1 for c in rows[3][2:] if c.strip())
    rows = [r for r in rows[5:] if any(c.strip() for c in r)]
    cells = [[c.strip() for c in r[2:]] for r in rows]
    used = max(max((i for i, c in enumerate(r) if c), default=-1) for r in cells) + 1
    width = 3 * max(named, -(-used // 3))
    out = np.full((len(rows), width), np.nan)
    for i, c in enumerate(cells):
        c = c[:width]
        out[i, :len(c)] = [float(x) if x else np.nan for x in c]
    out = out.reshape(len(rows), -1, 3)
    out[(out == 0.0).all(axis=2)] = np.nan
    return out


def trc_outcomes(files=None):
    files = sorted((CORPUS / "trc").iterdir()) if files is None else list(files)
    out = []
    for path in files:
        markers, notes, reason = _read(path)
        vendor = next((v for k, v in NAME_VENDORS.items() if k in path.name), "unknown")
        if markers is None:
            out.append(Outcome(path.name, "trc", vendor, 0, 0, "refused", "", notes, reason))
            continue
        agreement = "rows: " + compare(markers.positions, trc_rows(path))
        result = "read (warning)" if any(n.startswith("warning:") for n in notes) else "read"
        out.append(Outcome(path.name, "trc", vendor, markers.n_frames, markers.n_markers, result, agreement, notes))
    return out


def llf_rows(path):
    """(seconds from the first row (F,), names, values (F, K)) of a Live Link Face CSV, parsed plainly."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.reader(fh) if r]
    names = rows[0][2:]
    rate = 60.0  # these recordings' timecode frames run to 59

    def seconds(tc):
        h, m, s, f = tc.split(":")
        return int(h) * 3600 + int(m) * 60 + int(s) + float(f) / rate

    t = np.array([seconds(r[0]) for r in rows[1:]])
    return t - t[0], names, np.array([[float(x) for x in r[2:]] for r in rows[1:]])


def llf_errors(path):
    """Max |facecap - linear interpolation of the raw rows| over every frame and shape, and the frame count."""
    from facecap.solvers.io import read_weights

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        track = read_weights(path)
    t, names, values = llf_rows(path)
    lower = [n.lower() for n in names]
    tq = (track.frames - track.frames[0]) / track.fps
    cols = [lower.index(n.lower()) for n in track.names]
    ref = np.stack([np.interp(tq, t, values[:, j]) for j in cols], axis=1)
    return float(np.nanmax(np.abs(track.values - ref))), track


def llf_outcomes(files=None):
    files = sorted((CORPUS / "llf").iterdir()) if files is None else list(files)
    out = []
    for path in files:
        err, track = llf_errors(path)
        verdict = "exact" if err == 0 else f"max {err:.2g}"
        out.append(Outcome(path.name, "llf", NAME_VENDORS["llf_"], len(track.frames), len(track.names),
                           "read", f"linear interpolation of the rows: {verdict}", track.notes))
    return out


# --------------------------------------------------------------------------------------------
# the table


def table(outcomes):
    """Markdown table of ``outcomes`` with a summary line per kind."""
    lines = []
    for kind, title in (("c3d", "C3D"), ("trc", "TRC"), ("llf", "Live Link Face")):
        rows = [o for o in outcomes if o.kind == kind]
        if not rows:
            continue
        read = sum(o.result != "refused" for o in rows)
        agree = sum(o.result != "refused" and not o.agreement.startswith(("NONE", "header")) for o in rows)
        header = sum(o.agreement.startswith("header") for o in rows)
        lines += [f"### {title}: {len(rows)} files, {read} read ({agree} agree with a reference"
                  + (f", {header} with their own header" if header else "") + f"), {len(rows) - read} refused", ""]
        lines += ["| file | vendor | frames | markers | result | agreement |", "|---|---|---:|---:|---|---|"]
        for o in rows:
            result = o.result if o.result != "refused" else f"refused: {o.reason.split(': ', 1)[-1]}"
            warn = [n[len("warning: "):] for n in o.notes if n.startswith("warning:")]
            if warn:
                result += ": " + "; ".join(w[:110] for w in warn)
            cell = lambda text: str(text).replace("|", "\\|")  # noqa: E731
            lines.append(f"| {o.file} | {cell(o.vendor)} | {o.frames} | {o.markers} | {cell(result)} | {cell(o.agreement)} |")
        lines.append("")
    return "\n".join(lines)


def all_outcomes():
    return c3d_outcomes() + trc_outcomes() + llf_outcomes()


def write_doc(path, outcomes):
    """Replace the generated part of ``path`` (between the BEGIN/END markers) with the table."""
    begin, end = "<!-- BEGIN generated by tests/core/realdata_corpus.py -->", "<!-- END generated -->"
    text = Path(path).read_text(encoding="utf-8") if Path(path).exists() else f"{begin}\n{end}\n"
    head, rest = text.split(begin, 1)
    tail = rest.split(end, 1)[1]
    Path(path).write_text(f"{head}{begin}\n{table(outcomes)}\n{end}{tail}", encoding="utf-8")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--references", nargs="+", metavar=("DIR", "FILE"), help=argparse.SUPPRESS)
    parser.add_argument("--write", metavar="DOC", help="replace the generated table in DOC (docs/realdata.md)")
    parser.add_argument("--json", action="store_true", help="print the outcomes as JSON")
    args = parser.parse_args(argv)
    if args.references:
        dump_references([Path(p) for p in args.references[1:]], args.references[0])
        return 0
    outcomes = all_outcomes()
    if args.write:
        write_doc(args.write, outcomes)
    if args.json:
        print(json.dumps([o.__dict__ for o in outcomes], indent=1, default=list))
    else:
        print(table(outcomes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
