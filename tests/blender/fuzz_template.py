"""The command-line fuzz campaign's template and rig pieces (``test_fuzz_commands`` runs them with the others).

``template``: ``template convert`` on damaged and hostile copies of ICT-FaceKit (zips mutated byte by byte or in
their structure: encrypted members, methods Python cannot read, bombs, missing, duplicated, traversing or linked
members; folders with FIFOs, devices, loops and oversized files; altered ``ict_face.npz`` files), ``template fetch``
against a local server (mutated zips, endless, oversized, lying, trickling, silent, redirecting, failing answers) and
hostile addresses, and ``template info``; every ``--out`` from the campaign's hostile paths. ``rig``: retarget
configs with a ``[rig]`` whose corrective drivers cannot run (a function from the .blend's text module, an
``__import__`` that must never run, a syntax error, a variable whose target is gone).

Nothing here runs facecap: generators return ``Case`` objects (``setup`` makes what bytes cannot: FIFOs, links).
"""

import contextlib
import http.server
import json
import os
import struct
import time
import zipfile
from pathlib import Path

import numpy as np
from fuzz_commands import PATHS, SAMPLES, STABLE, Case, mutate_tables, toml_dumps
from ict_release_copy import serving
from shared_data import ICT_FACEKIT

from facecap.solvers.character.ict_release import FILES  # the names of what is read, not what reading does

FACE = 9409
TOKENS = [b"v ", b"f ", b"vt 0 0\n", b"-1", b"1e999", b"nan", b"\x00", b"\xff", b"/", b"f 1/1 2/2 3/3\n", b"\n" * 3]


def _neutral(faces=True):
    rng = np.random.default_rng(5)
    v = "".join(f"v {x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in rng.normal(size=(FACE, 3)))
    f = "".join(f"f {i + 1} {i + 2} {i + 3} {i + 4}\n" for i in range(0, 400, 4)) if faces else ""
    return ("# a copy\n" + v + f).encode()


def release_files(deep=False):
    """{FaceXModel file name: bytes}: every file the reader looks for, tiny (``deep``: a whole neutral, so that
    reading goes on to the first expression)."""
    files = {name: b"v 0 0 0\n" for name in FILES}
    files["generic_neutral_mesh.obj"] = _neutral() if deep else b"v 1 2 3\nf 1 1 1\n"
    files["vertex_indices.json"] = json.dumps({"idx_to_landmark_verts": list(range(68))}).encode()
    return files


def zip_bytes(files, prefix="ICT-FaceKit-x/FaceXModel/", method=zipfile.ZIP_DEFLATED):
    import io

    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", method) as z:
        for name, data in files.items():
            z.writestr(prefix + name, data)
    return out.getvalue()


def _patch_member(data, index, *, flag=None, method=None, size=None):
    """``data`` (a zip) with its ``index``-th member's flags, method or recorded size changed in both headers."""
    data = bytearray(data)
    central, at = [], data.find(b"PK\x01\x02")
    while at >= 0:
        central.append(at)
        at = data.find(b"PK\x01\x02", at + 4)
    if not central:
        return bytes(data)
    c = central[index % len(central)]
    local = struct.unpack_from("<I", data, c + 42)[0]
    for at, f_off, m_off, s_off in ((c, 8, 10, 24), (local, 6, 8, 22)):
        if at + s_off + 4 > len(data):
            continue
        if flag is not None:
            struct.pack_into("<H", data, at + f_off, struct.unpack_from("<H", data, at + f_off)[0] | flag)
        if method is not None:
            struct.pack_into("<H", data, at + m_off, method)
        if size is not None:
            struct.pack_into("<I", data, at + s_off, size)
    return bytes(data)


def _bomb():
    import io

    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in release_files().items():
            with z.open("ICT/FaceXModel/" + name, "w") as f:
                f.write(data)
                if name == "generic_neutral_mesh.obj":
                    for _ in range(40):
                        f.write(b"f 1 2 3 4\n" * 100_000)
    return out.getvalue()


class Seeds:
    """The campaign's template inputs, made once: tiny and deep releases (zip and folder), a bomb, a zip of too
    many entries, the reduced face file; and a local server for ``template fetch``."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.tiny, self.deep = zip_bytes(release_files()), zip_bytes(release_files(deep=True))
        self.bomb = _bomb()
        many = self.folder / "many.zip"
        with zipfile.ZipFile(many, "w") as z:
            for i in range(25_000):
                z.writestr(f"x/{i}", b"")
        self.many = many.read_bytes()
        many.unlink()
        self.npz = ICT_FACEKIT / "ict_face.npz"  # cases of it are left out where the shared data is not
        self.served = {}

    def zip_cases(self, rng, nrng):
        """(description, zip bytes): mutated byte by byte, or in structure."""
        base = self.deep if rng.random() < 0.3 else self.tiny
        op = rng.randrange(10)
        if op <= 2:
            from test_fuzz_io import mutate

            return "bytes", mutate(base, nrng)
        if op == 3:
            return "flag", _patch_member(base, rng.randrange(160), flag=rng.choice([1, 8, 64, 0x2000]))
        if op == 4:
            return "method", _patch_member(base, rng.randrange(160), method=rng.choice([1, 6, 9, 12, 14, 93, 95, 98,
                                                                                        99, 65535]))
        if op == 5:
            return "size", _patch_member(base, rng.randrange(160), size=rng.choice([0, 1, 2**31, 2**32 - 1, 16 << 20]))
        if op == 6:
            return "bomb", self.bomb
        if op == 7:
            return "many", self.many
        files = release_files(deep=base is self.deep)
        names = list(files)
        victim = rng.choice(names)
        change = rng.randrange(5)
        if change == 0:
            del files[victim]
        elif change == 1:
            files[victim] = files[victim] * rng.choice([2, 1000]) + rng.choice(TOKENS)
        elif change == 2:
            files["../../" + victim] = files.pop(victim)
        elif change == 3:
            files[victim] = b"v 0 0 0\n" * rng.choice([9409, 60000]) + b"f 1 2 3 4\n" * rng.choice([10, 60000])
        else:
            files[victim] = json.dumps({"idx_to_landmark_verts": rng.choice([[], [-1] * 68, [10 ** 30] * 68, "x",
                                                                             list(range(68))])}).encode()
        return "members", zip_bytes(files, prefix=rng.choice(["ICT-FaceKit-x/FaceXModel/", "", "/abs/FaceXModel/"]),
                                    method=rng.choice([zipfile.ZIP_DEFLATED, zipfile.ZIP_STORED, zipfile.ZIP_BZIP2]))

    def folder_case(self, rng, where):
        """A setup callable making a hostile FaceXModel folder at ``where`` (relative to the workspace)."""
        files = release_files(deep=rng.random() < 0.3)
        victim = rng.choice(list(files))
        how = rng.choice(["missing", "fifo", "dev", "loop", "dir", "sparse", "text", "link_out", "empty"])

        def setup(ws):
            fx = ws / where / "FaceXModel"
            fx.mkdir(parents=True)
            for name, data in files.items():
                (fx / name).write_bytes(data)
            target = fx / victim
            target.unlink()
            if how == "fifo":
                os.mkfifo(target)
            elif how == "dev":
                target.symlink_to("/dev/zero")
            elif how == "loop":
                target.symlink_to(target.name)
            elif how == "dir":
                target.mkdir()
            elif how == "sparse":
                with open(target, "wb") as f:
                    f.truncate(40 << 20)
            elif how == "text":
                target.write_bytes(files[victim].replace(b"v ", b"v x ", 1) + rng.choice(TOKENS))
            elif how == "link_out":
                target.symlink_to(ws / "notes.txt")
            elif how == "empty":
                target.write_bytes(b"")
        return setup

    def npz_case(self, rng, nrng, where):
        """A setup callable writing an altered ``ict_face.npz`` at ``where`` (made when the case runs: the campaign
        does not hold dozens of 9 MB files); None without the shared file."""
        if not self.npz.is_file():
            return None
        op, pick, seed = rng.randrange(6), rng.random(), rng.randrange(2 ** 32)

        def setup(ws):
            r = np.random.default_rng(seed)
            path = ws / where
            path.parent.mkdir(parents=True, exist_ok=True)
            if op == 5:  # cut short, or a few bytes changed
                from test_fuzz_io import mutate

                data = self.npz.read_bytes()
                path.write_bytes(data[: int(len(data) * pick)] if pick < 0.5 else mutate(data, r))
                return
            with np.load(self.npz) as z:
                d = {k: z[k] for k in z.files}
            keys = sorted(d)
            if op == 0:
                n = [str(x) for x in d["expression_names"]]
                i, j = r.choice(len(n), 2, replace=False)
                n[i], n[j] = n[j], n[i]
                d["expression_names"] = np.array(n)
            elif op == 1:
                d["landmarks_multipie68"] = d["landmarks_multipie68"][::-1].copy()
            elif op == 2:
                d["quads"] = d["quads"][: int(len(d["quads"]) * pick)]
            elif op == 3:
                del d[keys[int(pick * len(keys))]]
            else:
                d[keys[int(pick * len(keys))]] = [np.array([]), np.array(["x"]), np.array([[1, 2], [3, 4]]),
                                                  np.array(np.nan), np.zeros((3, 9409, 3), np.float32)][seed % 5]
            np.savez(path, **d)
        return setup

    # -- the local server for template fetch ---------------------------------------------------------------
    @contextlib.contextmanager
    def server(self):
        seeds = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):  # noqa: N802 (http.server's name)
                path = self.path.split("?")[0]
                try:
                    if path.startswith("/served/"):
                        body = seeds.served.get(path.rsplit("/", 1)[1])
                        if body is None:
                            return self.send_error(404)
                        self._send(body)
                    elif path == "/endless":
                        self._headers(None)
                        while True:
                            self.wfile.write(b"\0" * (1 << 16))
                    elif path == "/huge":
                        self._headers(10 << 30)
                    elif path in ("/liar", "/short"):
                        self._headers(10 if path == "/liar" else 1 << 20)
                        self.wfile.write(seeds.tiny[:1000])
                    elif path == "/trickle":
                        self._headers(None)
                        while True:
                            self.wfile.write(b"PK")
                            self.wfile.flush()
                            time.sleep(0.2)
                    elif path == "/silent":
                        time.sleep(5)
                    elif path == "/loop":
                        self.send_response(302)
                        self.send_header("Location", "/loop")
                        self.end_headers()
                    elif path == "/redirect":
                        self.send_response(301)
                        self.send_header("Location", "/served/tiny")
                        self.end_headers()
                    elif path == "/html":
                        self._send(b"<html><body>rate limited</body></html>")
                    else:
                        self.send_error(int(path.strip("/")) if path.strip("/").isdigit() else 404)
                except OSError:
                    pass  # the client stopped reading

            def _headers(self, length):
                self.send_response(200)
                if length is not None:
                    self.send_header("Content-Length", str(length))
                self.end_headers()

            def _send(self, body):
                self._headers(len(body))
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        self.served["tiny"] = self.tiny
        with serving(Handler) as url:
            yield url


OUT_PATHS = PATHS + ["o/t.npz", "o/t.npz", "o/t.npz", None, "cfg.toml", "src.zip", "tpl"]


def template_cases(ws, seeds, rng, nrng, n, url):
    """``n`` template cases (convert about 60 %, fetch 30 %, info 10 %)."""
    for i in range(n):
        out = rng.choice(OUT_PATHS)
        tail = ([] if out is None else ["--out", out]) + (["--overwrite"] if rng.random() < 0.1 else [])
        scratch = f"tpl/{i}"
        roll = rng.random()
        if roll < 0.6:
            kind = rng.random()
            if kind < 0.55:
                _, data = seeds.zip_cases(rng, nrng)
                yield Case("template", ["template", "convert", "src.zip", *tail], {"src.zip": data})
            elif kind < 0.85:
                yield Case("template", ["template", "convert", scratch, *tail], setup=seeds.folder_case(rng, scratch),
                           scratch="tpl")
            else:
                setup = seeds.npz_case(rng, nrng, f"{scratch}/ict_face.npz")
                if setup is None:
                    continue
                yield Case("template", ["template", "convert", f"{scratch}/ict_face.npz", *tail], setup=setup,
                           scratch="tpl")
        elif roll < 0.9:
            served = f"z{i}.zip"
            path = rng.choice(["/served/" + served] * 4 + ["/endless", "/huge", "/liar", "/short", "/trickle",
                                                           "/silent", "/loop", "/redirect", "/html", "/404", "/500",
                                                           "/served/tiny"])
            if path.startswith("/served/z"):
                seeds.served[served] = seeds.zip_cases(rng, nrng)[1]
            address = url + path if rng.random() < 0.9 else rng.choice([
                "file:///dev/zero", "ftp://127.0.0.1/x.zip", "not a url", "http://[::1", "http://127.0.0.1:1/x.zip",
                url + "/" + "a" * 5000, url + "/%2e%2e", url + "/..", url + "/.hidden.zip", "javascript:alert(1)"])
            yield Case("template", ["template", "fetch", "--url", address, *tail] + (["--keep"] if rng.random() < 0.2
                                                                                    else []))
        else:
            yield Case("template", ["template", "info", rng.choice(["notes.txt", "take.csv", "fifo", "adir", "loop",
                                                                    "src.zip", "character.blend", "missing.npz"])])


#: Drivers of the campaign's rig .blend: (shape key, expression, the key its variable reads)
RIG_DRIVERS = (("mouthSmileLeft", "ease(var)", "jawOpen"),  # the rig's function, from a text module not run
               ("mouthSmileRight", '__import__("os").system("touch RAN_driver") or var', "jawOpen"),  # never run
               ("mouthFrownLeft", "var +* 2", "jawOpen"),  # a syntax error
               ("mouthFrownRight", "var * 0.5", "jawOpen"))  # runs (a simple expression)


def make_rig_blend(folder):
    """``rig.blend``: the sample character with corrective drivers that cannot run, and a text module that
    registers their function (and would touch RAN_text_module if it ever ran)."""
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(SAMPLES / "character.blend"), load_ui=False)
    key = bpy.data.objects["Face"].data.shape_keys
    for target, expression, source in RIG_DRIVERS:
        d = key.key_blocks[target].driver_add("value").driver
        d.type = "SCRIPTED"
        v = d.variables.new()
        v.name, v.type = "var", "SINGLE_PROP"
        v.targets[0].id_type, v.targets[0].id = "KEY", key
        v.targets[0].data_path = f'key_blocks["{source}"].value'
        d.expression = expression
    text = bpy.data.texts.new("rig_functions.py")
    text.write('import bpy, pathlib\npathlib.Path("RAN_text_module").touch()\n'
               'def ease(x):\n    return x * x * (3 - 2 * x)\nbpy.app.driver_namespace["ease"] = ease\n')
    text.use_module = True
    bpy.ops.wm.save_as_mainfile(filepath=str(Path(folder) / "rig.blend"))
    bpy.ops.wm.read_factory_settings(use_empty=True)


def rig_cases(ws, rng, n):
    for _ in range(n):
        base = ws.retarget_config("geometric")
        base["target"]["blend"] = "rig.blend"
        base["stabilise"]["markers"] = list(STABLE)
        base["rig"] = {"preset": "shape_keys", "object": "Face", "probes": 64}
        data = mutate_tables(base, rng) if rng.random() < 0.7 else base
        yield Case("rig", ["retarget", "--config", "cfg.toml"], {"cfg.toml": toml_dumps(data).encode()})


def litter(folder):
    """Temporary files left anywhere under ``folder`` (a download's, an output's)."""
    return [str(p.relative_to(folder)) for p in Path(folder).rglob("*") if ".facecap-tmp." in p.name
            or p.name.startswith("RAN_")]
