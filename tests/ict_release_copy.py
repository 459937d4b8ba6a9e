"""A copy of ICT-FaceKit as its authors publish it (``FaceXModel/*.obj``, ``vertex_indices.json``), rebuilt from the
shared reduced file so that the conversion from OBJ files can be tested without a download.

Each coordinate is written with the fewest digits (6 first, as the release's OBJ files have them) that give back the
reduced file's float32 delta, and "-0" where the release has it, so the copy converts to the same data digest as the
release; the back of the head (vertices after the face region) and polygons among them are added as the release has
them after the face region."""

import contextlib
import http.server
import json
import threading
import time
from pathlib import Path

import numpy as np

BACK_OF_HEAD = 12


def _rows(text):
    return "".join(f"v {a} {b} {c}\n" for a, b, c in text)


def write_ict_release(npz, folder):
    """Write ``folder/FaceXModel`` from the reduced face file ``npz``; returns ``folder``."""
    d = np.load(npz)
    fx = Path(folder) / "FaceXModel"
    fx.mkdir(parents=True, exist_ok=True)
    head = "# ICT FaceKit (a test copy)\n\nmtllib ICTFaceModelMaterial.mtl\n"
    neutral_text = np.char.mod("%.6g", d["neutral_cm"].astype(np.float64))
    neutral = neutral_text.astype(np.float64)
    V = len(neutral)
    back = _rows(np.char.mod("%.6g", neutral[:BACK_OF_HEAD] * [1.0, 1.0, -1.0]))
    faces = "".join("f " + " ".join(f"{i + 1}/{i + 1}" for i in q) + "\n" for q in d["quads"])
    faces += f"f {V} {V + 1} {V + 2}\nf {V + 3}/1/1 {V + 4}/2/2 {V + 5}/3/3 {V + 6}/4/4\n"  # reaching the back
    (fx / "generic_neutral_mesh.obj").write_text(head + _rows(neutral_text) + back + "vt 0.5 0.5\n" + faces)

    def shape(name, delta):
        want = neutral + delta.astype(np.float64)
        text = np.char.mod("%.6g", want).astype("U24")
        for digits in (7, 8, 9, 12):
            off = (text.astype(np.float64) - neutral).astype(np.float32) != delta
            if not off.any():
                break
            text[off] = np.char.mod(f"%.{digits}g", want[off])
        text[np.signbit(delta) & (delta == 0) & (neutral == 0)] = "-0"
        (fx / f"{name}.obj").write_text(head + _rows(text) + back + faces)

    for name, delta in zip(d["expression_names"], d["expression_deltas_cm"]):
        shape(str(name), delta)
    for i, delta in enumerate(d["identity_deltas_cm"]):
        shape(f"identity{i:03d}", delta)
    (fx / "vertex_indices.json").write_text(json.dumps({
        "expressions": [str(n) for n in d["expression_names"]],
        "idx_to_landmark_verts": d["landmarks_multipie68"].tolist()}))
    return Path(folder)


@contextlib.contextmanager
def serve_release(archive):
    """A local web server for the zip ``archive``: ``/ict.zip`` whole, ``/cut.zip`` announced whole but cut after a
    third, ``/slow.zip`` a megabyte every 0.2 s; anything else 404. Yields its address."""
    data = Path(archive).read_bytes()

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 (http.server's name)
            if self.path not in ("/ict.zip", "/cut.zip", "/slow.zip"):
                self.send_error(404)
                return
            self.send_response(200)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            try:
                if self.path == "/ict.zip":
                    self.wfile.write(data)
                elif self.path == "/cut.zip":
                    self.wfile.write(data[: len(data) // 3])
                else:
                    for i in range(0, len(data), 1 << 20):
                        self.wfile.write(data[i:i + (1 << 20)])
                        time.sleep(0.2)
            except (BrokenPipeError, ConnectionResetError):
                pass  # the client stopped reading (a cancelled download)

        def log_message(self, *args):
            pass

    with serving(Handler) as url:
        yield url


@contextlib.contextmanager
def serving(handler):
    """A local web server (127.0.0.1, a free port) answering with ``handler`` (a BaseHTTPRequestHandler class) on
    threads of its own; yields its address and stops it afterwards."""
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    httpd.daemon_threads = True
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}"
    finally:
        httpd.shutdown()
        httpd.server_close()
