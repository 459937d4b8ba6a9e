"""Regression tests named after the defects of the third reliability campaign (``shared/bugs/reliability-3``) that
need no Blender: the template command's outputs, archives and downloads (01-06) and CSV cells a spreadsheet would
run (09). (Signals, Blender's temporary folder and rigs whose drivers cannot run:
``tests/e2e/test_reliability3_cli.py``.)"""

import csv
import http.server
import os
import re
import struct
import subprocess
import sys
import time
import zipfile
from types import SimpleNamespace

import numpy as np
import pytest
from ict_release_copy import serving
from shared_data import ICT_FACEKIT, require

from facecap.facecap_addon import cli
from facecap.solvers.character.face_model import ICT_FILE
from facecap.solvers.character.ict_release import FILES, FOLDER, NEUTRAL, RELEASE_POLYGONS, read_release
from facecap.solvers.character.template import FORMAT, TEMPLATE_DIGEST, HumanTemplate, convert, template_path
from facecap.solvers.errors import FacecapError, InputFileError
from facecap.solvers.io import import_markers, read_weights, write_markers
from facecap.solvers.io.csv import read_weights_csv
from facecap.solvers.io.csv_write import formula_safe, text_of_cell, write_weights_csv
from facecap.solvers.io.files import machine_tag
from facecap.solvers.markers import MarkerSet
from facecap.solvers.tools.batch_summary import new_record, to_csv
from facecap.solvers.tools.template import download, fetch
from facecap.solvers.tuning.store import read_corrections_csv

FORMULAS = ('=HYPERLINK("http://example.invalid","click")', "+1+1", "@SUM(1)", "-1+1", "\tx", "'=quoted", "''",
            "'plain", "plain", "a=b")


def formulas(path_or_rows):
    """The cells a spreadsheet would run: text (not a number) starting with = + - @ or a tab."""
    if not isinstance(path_or_rows, list):
        with open(path_or_rows, newline="", encoding="utf-8") as fh:
            path_or_rows = list(csv.reader(fh))
    out = []
    for cell in (c for row in path_or_rows for c in row if c[:1] and c[:1] in "=+-@\t"):
        try:
            float(cell)
        except ValueError:
            out.append(cell)
    return out


def test_09_formula_like_names_are_text_in_every_csv_and_read_back_as_written(tmp_path):
    """A spreadsheet runs a cell that starts with = + - @ (or a tab): facecap writes it after a ', as OWASP
    advises, and its own readers give back the original name (weights, markers, corrections)."""
    for name in FORMULAS:
        assert text_of_cell(formula_safe(name)) == name
    rng = np.random.default_rng(9)
    names = list(FORMULAS)
    write_weights_csv(tmp_path / "w.csv", np.arange(1, 4), names, rng.random((3, len(names))))
    assert not formulas(tmp_path / "w.csv")
    assert read_weights_csv(tmp_path / "w.csv")[1] == tuple(names)
    assert tuple(read_weights(tmp_path / "w.csv").names) == tuple(names)
    corrections = read_corrections_csv(tmp_path / "w.csv")
    assert set(corrections[1.0]) == set(names)
    markers = [n for n in names if n.strip() == n]
    m = MarkerSet(tuple(markers), np.arange(1, 4), rng.normal(size=(3, len(markers), 3)), fps=60, units="mm",
                  segments={"=cmd|' /C calc'!A0": [(1.0, 2.0)]})
    write_markers(tmp_path / "m.csv", m)
    assert not formulas(tmp_path / "m.csv")
    back = import_markers(tmp_path / "m.csv").markers
    assert back.names == m.names and list(back.segments) == list(m.segments)
    np.testing.assert_allclose(back.positions, m.positions, rtol=1e-6)


def test_09_the_batch_summary_csv_holds_no_formula(tmp_path):
    take = SimpleNamespace(name="=1+1", path=tmp_path / "=1+1.toml", listed_by=None)
    record = new_record(take, status="failed", error="-bad: @it")
    text = to_csv([record])
    row = next(csv.reader(text.splitlines()[1:]))
    assert row[0] == "'=1+1" and row[2] == "'-bad: @it" and not formulas([row])


# -- the template command: outputs (01), archives (02, 03), digest (04), downloads (05, 06) -----------------------


def run(*argv):
    """``python -m facecap`` in this process: (exit status, stderr lines)."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    err = io.StringIO()
    with redirect_stderr(err), redirect_stdout(io.StringIO()):
        rc = cli.main([str(a) for a in argv])
    return rc, err.getvalue().strip().splitlines()


@pytest.fixture
def ict(tmp_path, monkeypatch):
    monkeypatch.setenv("FACECAP_DATA", str(tmp_path / "data"))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "src.npz").write_bytes((require(ICT_FACEKIT) / ICT_FILE).read_bytes())
    return tmp_path / "src.npz"


def test_01_template_convert_never_replaces_its_source_or_someone_elses_file(ict, tmp_path):
    (tmp_path / "notes.txt").write_text("my notes\n")
    (tmp_path / "character.blend").write_bytes(b"BLENDER-v500 not really\n")
    (tmp_path / "adir").mkdir()
    for out, message in (("src.npz", "is the same file as the ICT-FaceKit download"),
                         ("character.blend", "exists and is not a facecap human template"),
                         ("notes.txt", "exists and is not a facecap human template .* --overwrite"),
                         ("adir", "is a folder")):
        before = (tmp_path / out).read_bytes() if (tmp_path / out).is_file() else None
        rc, err = run("template", "convert", "src.npz", "--out", out)
        assert rc == 1 and len(err) == 1 and re.search(message, err[0]), (out, err)
        assert before is None or (tmp_path / out).read_bytes() == before
    rc, err = run("template", "convert", "src.npz", "--out", "src.npz", "--overwrite")
    assert rc == 1 and "is the same file as" in err[0]  # no flag allows writing over the source
    assert run("template", "convert", "src.npz", "--out", "notes.txt", "--overwrite")[0] == 0
    assert HumanTemplate.load(tmp_path / "notes.txt").model.digest == TEMPLATE_DIGEST
    assert run("template", "convert", "src.npz", "--out", "t.npz")[0] == 0
    assert run("template", "convert", "src.npz", "--out", "t.npz")[0] == 0  # its own earlier output is replaced
    template_path().parent.mkdir(parents=True)
    template_path().write_bytes(b"whatever was there")  # facecap's own data folder: replaced as it is
    assert run("template", "convert", "src.npz")[0] == 0 and HumanTemplate.load(template_path())
    rc, err = run("template", "fetch", "--url", "http://127.0.0.1:9/none.zip", "--out", "character.blend")
    assert rc == 1 and "exists and is not" in err[0]  # checked before any download


def full_zip(path, *, neutral=b"v 0 0 0\n", prefix="ICT-FaceKit-x/FaceXModel/"):
    """A zip with every file the release's reader reads (tiny ones), ``neutral`` as the neutral OBJ."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name in FILES:
            z.writestr(prefix + name, neutral if name == NEUTRAL else b"v 0 0 0\n")
    return path


def set_member(path, name, *, method=None, encrypted=False):
    """Mark member ``name`` of the zip at ``path`` encrypted or compressed with ``method`` (both headers)."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info, start = z.getinfo(name), z.start_dir
    at = {"local": info.header_offset, "central": data.index(name.encode(), start) - 46}
    assert data[at["central"]:at["central"] + 4] == b"PK\x01\x02"
    for where, flag, meth in (("local", 6, 8), ("central", 8, 10)):
        i = at[where]
        if encrypted:
            data[i + flag] |= 1
        if method is not None:
            data[i + meth:i + meth + 2] = struct.pack("<H", method)
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage, message", [({"encrypted": True}, "is encrypted"),
                                             ({"method": 9}, "is compressed with Deflate64 .*cannot read"),
                                             ({"method": 99}, "is compressed with AES encryption .*cannot read"),
                                             ({"method": 6}, "is compressed with Implode")])
def test_02_an_unreadable_member_of_a_whole_release_zip_is_named_as_a_bad_download(tmp_path, damage, message):
    path = full_zip(tmp_path / "ict.zip")
    set_member(path, f"ICT-FaceKit-x/{FOLDER}/identity050.obj", **damage)
    with pytest.raises(InputFileError, match=f"identity050.obj {message}.*a bad download.*download it again") as caught:
        read_release(path)
    assert "\n" not in str(caught.value)
    rc, err = run("template", "convert", path, "--out", tmp_path / "t.npz")
    assert rc == 1 and err[-1].startswith("facecap: error:") and "internal error" not in err[-1]
    assert not (tmp_path / "t.npz").exists()


def test_03_a_zip_bomb_is_refused_before_it_is_read(tmp_path):
    """300 MB of polygons packed into under a megabyte: refused from the zip's directory, at once."""
    path = tmp_path / "bomb.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name in FILES:
            with z.open(f"ICT/{FOLDER}/{name}", "w") as f:
                if name == NEUTRAL:
                    f.write(b"v 0 0 0\n" * 9409)
                    for _ in range(300):
                        f.write(b"f 1 2 3 4\n" * 100_000)
                else:
                    f.write(b"v 0 0 0\n")
    assert path.stat().st_size < 2 << 20
    start = time.perf_counter()
    with pytest.raises(InputFileError, match=r"generic_neutral_mesh.obj is 286.2 MiB unpacked; at most 16.0 MiB"):
        read_release(path)
    assert time.perf_counter() - start < 2.0
    ratio = full_zip(tmp_path / "ratio.zip", neutral=b"v 0 0 0\n" * 9409 + b"f 1 2 3 4\n" * 1_500_000)
    with pytest.raises(InputFileError, match=r"unpacks \d+ times its packed size \(a zip bomb"):
        read_release(ratio)


def test_03_obj_counts_are_capped_by_what_the_release_holds(tmp_path):
    """Within the size limits (a folder: nothing compressed), an OBJ holding more polygons or lines than the
    release's is not ICT-FaceKit's: refused as soon as the count passes, not read to its end."""
    fx = tmp_path / "ICT" / FOLDER
    fx.mkdir(parents=True)
    for name in FILES:
        (fx / name).write_bytes(b"v 0 0 0\n")
    (fx / NEUTRAL).write_bytes(b"v 0 0 0\n" * 9409 + b"f 1 2 3 4\n" * (2 * RELEASE_POLYGONS + 10))
    with pytest.raises(InputFileError, match=rf"line {9409 + 2 * RELEASE_POLYGONS + 1}: more than "
                                             rf"{2 * RELEASE_POLYGONS} polygons; ICT-FaceKit's head has"):
        read_release(tmp_path / "ICT")
    (fx / NEUTRAL).write_bytes(b"#\n" * 500_000)
    with pytest.raises(InputFileError, match=r"line 400001: more than 400000 lines"):
        read_release(tmp_path / "ICT")
    (fx / "identity050.obj").unlink()
    os.mkfifo(fx / "identity050.obj")  # never opened: it would block the reader for ever
    with pytest.raises(InputFileError, match=r"identity050.obj: not a regular file"):
        read_release(tmp_path / "ICT")


def altered(tmp_path, change):
    with np.load(require(ICT_FACEKIT) / ICT_FILE) as z:
        d = {k: z[k] for k in z.files}
    change(d)
    path = tmp_path / change.__name__ / ICT_FILE
    path.parent.mkdir()
    np.savez(path, **d)
    return path


def swap_names(d):
    n = [str(x) for x in d["expression_names"]]
    a, b = n.index("jawOpen"), n.index("mouthClose")
    n[a], n[b] = n[b], n[a]
    d["expression_names"] = np.array(n)


def reverse_landmarks(d):
    d["landmarks_multipie68"] = d["landmarks_multipie68"][::-1].copy()


def half_the_polygons(d):
    d["quads"] = d["quads"][: len(d["quads"]) // 2]


@pytest.mark.parametrize("change", [swap_names, reverse_landmarks, half_the_polygons])
def test_04_the_digest_covers_names_polygons_and_landmarks(tmp_path, change):
    source = altered(tmp_path, change)
    with pytest.raises(FacecapError, match="not the ICT-FaceKit release facecap knows"):
        convert(source, tmp_path / "t.npz")
    assert not (tmp_path / "t.npz").exists()
    with pytest.raises(FacecapError, match="not the ICT-FaceKit release facecap knows"):
        HumanTemplate.load(source)  # an ICT face file named by [actor] template


def test_04_installed_templates_are_checked_when_loaded_earlier_ones_keep_working(tmp_path):
    out = convert(require(ICT_FACEKIT), tmp_path / "t.npz")
    with np.load(out) as z:
        arrays = {k: z[k] for k in z.files}
    earlier = dict(arrays, digest=np.array("f48716ad59ed5db7f3eabea3c933da95d94637ffd2b2093f1f75770a243a3b2d"))
    np.savez_compressed(tmp_path / "earlier.npz", **earlier)  # as facecap wrote it before the digest covered all
    assert HumanTemplate.load(tmp_path / "earlier.npz").model.digest == TEMPLATE_DIGEST
    names = list(arrays["shape_names"])
    a, b = names.index("jawOpen"), names.index("mouthClose")
    names[a], names[b] = names[b], names[a]
    for key, value in (("shape_names", np.array(names)), ("landmarks68", arrays["landmarks68"][::-1].copy()),
                       ("triangles", arrays["triangles"][::2].copy()), ("deltas", arrays["deltas"] * 1.001)):
        np.savez_compressed(tmp_path / "changed.npz", **dict(arrays, **{key: value}))
        with pytest.raises(InputFileError, match="changed or damaged since it was installed.*install it again: "
                                                 "`python -m facecap template fetch`"):
            HumanTemplate.load(tmp_path / "changed.npz")
    np.savez_compressed(tmp_path / "huge.npz", format=np.array(FORMAT), deltas=np.zeros((600, 9409, 3), np.float32))
    with pytest.raises(InputFileError, match="deltas.npy is .* unpacked; at most 64.0 MiB"):
        HumanTemplate.load(tmp_path / "huge.npz")  # refused before its arrays are read


class Endless(http.server.BaseHTTPRequestHandler):
    """``/endless``: zeros without end and no Content-Length; ``/huge``: announces 10 GB; ``/trickle``: a byte
    every 0.1 s."""

    def do_GET(self):  # noqa: N802 (http.server's name)
        self.send_response(200)
        if self.path == "/huge":
            self.send_header("Content-Length", str(10 << 30))
        self.end_headers()
        try:
            while True:
                self.wfile.write(b"\0" * (1 << 16) if self.path != "/trickle" else b"\0")
                if self.path == "/trickle":
                    self.wfile.flush()
                    time.sleep(0.1)
                elif self.path == "/huge":
                    return
        except OSError:
            pass

    def log_message(self, *args):
        pass


def test_05_downloads_are_capped_in_size_and_time_and_leave_nothing(tmp_path):
    cache = tmp_path / "cache"
    with serving(Endless) as url:
        with pytest.raises(FacecapError, match=r"more than 4 MiB came .*stopped"):
            download(f"{url}/endless", cache / "ict.zip", max_bytes=4 << 20)
        start = time.monotonic()
        with pytest.raises(FacecapError, match=r"announces 10240 MiB"):
            download(f"{url}/huge", cache / "ict.zip")
        assert time.monotonic() - start < 5
        with pytest.raises(FacecapError, match=r"not finished after .* minutes"):
            download(f"{url}/trickle", cache / "ict.zip", deadline=0.5)
    assert os.listdir(cache) == []
    for url in ("file:///dev/zero", "ftp://example.invalid/x.zip"):
        with pytest.raises(FacecapError, match="not an http\\(s\\) address"):
            download(url, cache / "ict.zip")


def test_06_partial_downloads_of_killed_fetches_are_removed_by_the_next(tmp_path, ict):
    """Dead writers' partial downloads (and an older facecap's ``<name>.part-<pid>``) go; a live one stays."""
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    cache = tmp_path / "cache"
    cache.mkdir()
    stale = [cache / f".ict.zip.facecap-tmp.{machine_tag()}.{pid}.abc.zip", cache / f"ICT-FaceKit.zip.part-{pid}"]
    live = cache / f".other.zip.facecap-tmp.{machine_tag()}.{os.getpid()}.def.zip"
    for p in stale + [live]:
        p.write_bytes(b"\0" * 1000)
    with pytest.raises(FacecapError):  # nothing listens there: the fetch fails, after cleaning up
        fetch("http://127.0.0.1:9/ict.zip", tmp_path / "t.npz", cache=cache)
    assert sorted(os.listdir(cache)) == [live.name]
