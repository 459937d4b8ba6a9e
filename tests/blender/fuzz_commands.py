"""The command-line fuzz campaign's pieces: a workspace of inputs, a TOML writer, and seeded generators of
hostile configs, capture files and output paths for every command (``test_fuzz_commands`` runs them).

Every case is (command line, files it writes first, and how its inputs must look afterwards). Generators
take a ``random.Random`` and return cases; nothing here runs facecap.
"""

import json
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"
STABLE = ["head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R",
          "head_nose_bridge_C"]
FRAMES = 30

#: Values a user (or a typo, or damage) can put in a config
HOSTILE = ["", " ", "x", "a\u0000b", "点", "a" * 3000, -1, 0, 1, 2, 7, 10 ** 30, -(2 ** 63), 0.5, -0.0, 1e308,
           -1e308, 1e-320, math.nan, math.inf, -math.inf, True, False, [], [1, 2], [1, 2, 3, 4], ["a", "b", "c"],
           [[1, 2], [3, 4]], [math.nan, 0, 10, 10], {}, {"a": 1}, {"*": {"gain": 1e308}}, "auto", "mm", "bu", "px",
           "geometric", "parallel", "linear", "lk", "dis", "Z", "Y", "csv", "c3d"]
#: Section and key names near the real ones (typos), and others
NAMES = ["stabilize", "nuetral", "outptu", "solv", "tracking", "flow", "clean", "batch", "defaults", "x", "",
         "markers", "frames", "strategy", "fps", "units", "blend", "weights", "report", "smoothing", "regularisaton",
         "object", "video", "points", "method", "win_size", "levels", "takes", "controls", "tuning"]


def toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=True)  # JSON's escapes are TOML's basic-string escapes
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_dumps(data):
    """TOML text of ``data``: {section: {key: value}} (a non-table section value is written as a key)."""
    lines = []
    for section, body in data.items():
        if not isinstance(body, dict):
            lines.append(f"{json.dumps(section)} = {toml_value(body)}")
    for section, body in data.items():
        if isinstance(body, dict):
            lines.append(f"[{json.dumps(section)}]")
            lines += [f"{json.dumps(str(k))} = {toml_value(v)}" for k, v in body.items()]
    return "\n".join(lines) + "\n"


@dataclass
class Case:
    """One command line to run in ``folder``, after writing ``files`` ({name: bytes}) and calling ``setup(folder)``
    (what bytes cannot make: FIFOs, links); the folder ``scratch`` (relative) is removed afterwards."""

    family: str
    argv: list
    files: dict = field(default_factory=dict)
    full_run: bool = False  # whether a valid config is solved to the end (else checked up to the preflight)
    setup: object = None
    scratch: str = None


class Workspace:
    """The inputs every case reads, made once: the sample character, a 30-frame take, solved weights, a
    6-frame image sequence with seed points, a batch folder; and files no command may touch: a FIFO, a
    folder, a note that is nobody's output."""

    def __init__(self, folder):
        self.folder = Path(folder)
        f = self.folder
        f.mkdir(parents=True, exist_ok=True)
        shutil.copy(SAMPLES / "character.blend", f / "character.blend")
        lines = (SAMPLES / "sample_take.csv").read_text().splitlines()
        (f / "take.csv").write_text("\n".join(lines[:FRAMES + 1]) + "\n")
        lines = (SAMPLES / "sample_take_weights.csv").read_text().splitlines()
        (f / "weights.csv").write_text("\n".join(lines[:FRAMES + 1]) + "\n")
        self._clip()
        (f / "notes.txt").write_text("a user's notes: no facecap output\n")
        (f / "adir").mkdir(exist_ok=True)
        os.mkfifo(f / "fifo")
        (f / "loop").symlink_to("loop")
        (f / "link.csv").symlink_to("take.csv")
        os.link(f / "take.csv", f / "hard.csv")
        shoot = f / "shoot"
        shoot.mkdir()
        (shoot / "take_a.toml").write_text('[source]\nmarkers = "../take.csv"\n')
        (shoot / "take_b.toml").write_text('[source]\nmarkers = "../take.csv"\n[output]\naction = "b"\n')
        self.freeze()

    def freeze(self):
        """Take the files now in the folder as the inputs no case may change (again after adding some)."""
        f = self.folder
        self.inputs = sorted(p for p in f.rglob("*") if p.is_file() and not p.is_symlink() and p.stat().st_nlink == 1
                             or p.name == "take.csv")
        self.digest = self.snapshot()

    def _clip(self):
        import cv2  # OpenCV: only the clip needs it

        rng = np.random.default_rng(3)
        base = (rng.random((48, 64)) * 255).astype(np.uint8)
        base = cv2.GaussianBlur(base, (5, 5), 1.5)
        (self.folder / "seq").mkdir()
        for i in range(6):
            cv2.imwrite(str(self.folder / "seq" / f"f{i + 1:03d}.png"), np.roll(base, i, axis=1))
        (self.folder / "points.csv").write_text("name,x,y\np0,20,20\np1,40,24\np2,30,30\n")

    def snapshot(self):
        """(name, size, bytes hash) of every input, and the kinds of the special files."""
        import hashlib

        out = {str(p.relative_to(self.folder)): hashlib.sha256(p.read_bytes()).hexdigest() for p in self.inputs}
        out["fifo"] = "fifo" if Path(self.folder / "fifo").is_fifo() else "changed"
        out["adir"] = "dir" if (self.folder / "adir").is_dir() else "changed"
        return out

    # -- base configs -----------------------------------------------------------------------------------------
    def retarget_config(self, strategy="parallel", out="o"):
        data = {"target": {"blend": "character.blend", "object": "Face"},
                "source": {"markers": "take.csv", "units": "mm", "fps": 60},
                "stabilise": {"markers": list(STABLE)}, "neutral": {"frames": [1, 10]},
                "output": {"weights": f"{out}/w.csv", "report": f"{out}/r.json"}}
        if strategy == "parallel":
            data["source"] = {"weights": "weights.csv"}
            data["solve"] = {"strategy": "parallel"}
            del data["stabilise"], data["neutral"]
        return data

    @staticmethod
    def track_config(out="o"):
        return {"source": {"video": "seq/f%03d.png", "fps": 30}, "tracking": {"points": "points.csv", "method": "lk"},
                "output": {"markers": f"{out}/tracks.csv", "report": f"{out}/track.json"}}

    @staticmethod
    def batch_file():
        return {"batch": {"takes": ["shoot/"]},
                "defaults": {"target": {"blend": "character.blend", "object": "Face"},
                             "source": {"units": "mm", "fps": 60}, "stabilise": {"markers": list(STABLE)},
                             "neutral": {"frames": [1, 10]}, "output": {"weights": "out/{take}.csv"}}}


def mutate_tables(data, rng, values=HOSTILE):
    """1-3 random edits of config tables: a value replaced, a key removed, renamed or added, a section
    renamed, removed or added."""
    data = json.loads(json.dumps(data))  # a deep copy (the bases hold plain JSON types)
    for _ in range(rng.randint(1, 3)):
        op = rng.randrange(7)
        sections = [s for s, b in data.items() if isinstance(b, dict)]
        section = rng.choice(sections) if sections else None
        body = data.get(section) if section else None
        keys = list(body) if isinstance(body, dict) else []
        if op == 0 and keys:
            body[rng.choice(keys)] = rng.choice(values)
        elif op == 1 and keys:
            del body[rng.choice(keys)]
        elif op == 2 and keys:
            body[rng.choice(NAMES)] = body.pop(rng.choice(keys))
        elif op == 3 and section:
            body[rng.choice(NAMES)] = rng.choice(values)
        elif op == 4 and section:
            data[rng.choice(NAMES)] = data.pop(section)
        elif op == 5 and section:
            del data[section]
        else:
            data[rng.choice(NAMES)] = rng.choice([{}, {"x": 1}, rng.choice(values)])
    return data


#: Path values a config or command line may name: inputs, special files, folders, loops, odd spellings
PATHS = ["take.csv", "./sub/../take.csv", "link.csv", "hard.csv", "character.blend", "weights.csv", "points.csv",
         "fifo", "adir", "loop/x.csv", "notes.txt", "seq/f003.png", "seq", "missing/deep/x.csv", "cfg.toml",
         "o/x.csv", "o", "o/x.csv/y.csv", "~/../" + "x" * 300 + ".csv", "o/" + "n" * 250 + ".csv", "/proc/self/x.csv",
         "o/ok.json", "o/ok.blend", "o/ok.glb", "o/ok.html"]
