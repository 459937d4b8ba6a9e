"""Seeded hostile variants of the sample config, run in-process as far as the solve (everything the CLI
does before Blender keys): each ends in a solve or in a project error of one line per problem (a config's
problems are reported all at once), never a traceback, never a hang, never a write over an input."""

import hashlib
import math
import random
import shutil
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from facecap.facecap_addon.headless.headless import preflight, read_take
from facecap.solvers.character.basis import Basis
from facecap.solvers.config import load_take_config
from facecap.solvers.config.checks import check_against_take
from facecap.solvers.errors import FacecapError
from facecap.solvers.options import OPTIONS
from facecap.solvers.pipeline import SAMPLES_CHARACTER
from facecap.solvers.solve import SolveRequest, solve
from facecap.solvers.strategies.base import Target

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"
VARIANTS = 320
FRAMES = 120

HOSTILE = [float("nan"), float("inf"), -float("inf"), -1, 0, 1, 0.5, 1e308, -1e308, 10**30, 2**63, 2**31 + 5, 3.7,
           "", "auto", "x\0y", "../../escaped.csv", "~/x.csv", "take.toml", "take.csv", "out/same.csv", [], [0],
           [1, 2], [2, 1], [1, 10**18], [[1, 30], [100, 200]], [[[[1]]]], {}, {"x": 1}, {"*": 1e308}, True, False,
           "geometric", "calibrated", "parallel", "pca", "rigid", "similarity", [1.0, 0.0, 1.0]]


def _value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\0", "\\u0000") + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return "{ " + ", ".join(f'"{k}" = {_value(x)}' for k, x in v.items()) + " }"


def dump(data):
    return "".join(f"[{section}]\n" + "".join(f'"{k}" = {_value(v)}\n' for k, v in body.items())
                   for section, body in data.items())


def plausible(o, rng):
    """A value of option ``o``'s own kind and range (legal, or at its edges)."""
    kind = o.kind[0] if isinstance(o.kind, tuple) else o.kind
    if kind == "choice":
        return rng.choice(o.choices)
    if kind in ("float", "int"):
        lo = o.low if o.low is not None else (o.above if o.above is not None else -10)
        hi = o.high if o.high is not None else lo + 100
        value = rng.choice([lo, hi, lo + (hi - lo) * rng.random()])
        return int(value) if kind == "int" else float(value)
    if kind == "bool":
        return rng.random() < 0.5
    if kind == "floats":
        return [plausible(type(o)(o.section, o.key, "float", low=o.low, high=o.high, above=o.above), rng)
                for _ in range(o.length)]
    return o.default if o.default is not None else rng.choice(HOSTILE)


def mutate(base, rng):
    """A variant: 1-3 mutations of keys from the option table (and a few structural ones)."""
    data = {s: dict(b) for s, b in base.items()}
    for _ in range(rng.randint(1, 3)):
        roll = rng.random()
        if roll < 0.75:
            o = rng.choice(OPTIONS)
            if o.key.startswith("<"):
                continue
            data.setdefault(o.section, {})[o.key] = plausible(o, rng) if rng.random() < 0.5 else rng.choice(HOSTILE)
        elif roll < 0.85:
            section = rng.choice(list(data))
            if data[section]:
                del data[section][rng.choice(list(data[section]))]
        elif roll < 0.92:
            data.setdefault(rng.choice(["solve", "nonsense"]), {})["unknown_key"] = 1
        else:
            data["neutral"]["frames"] = rng.choice([[700, 800], [715, 900], [0, 0], [-5, 10], [[1, 10], [FRAMES + 1, 999]]])
    return data


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz")
    lines = (SAMPLES / "sample_take.csv").read_text().splitlines()
    (folder / "take.csv").write_text("\n".join(lines[: FRAMES + 1]) + "\n")
    shutil.copy(SAMPLES / "character.blend", folder / "character.blend")
    base = tomllib.loads((SAMPLES / "sample_take.toml").read_text())
    base["source"]["markers"] = "take.csv"
    base["neutral"]["frames"] = [1, 30]
    return folder, base, Basis.load_npz(SAMPLES / "character_basis.npz")


def run_variant(folder, text, basis):
    """Load, check and solve ``text`` as the CLI would before keying; returns 'solved' or the error."""
    path = folder / "take.toml"
    path.write_text(text, encoding="utf-8")
    try:
        config = load_take_config(path)
        preflight(config)
        take = read_take(config, lambda m: None)
        check_against_take(config, take.markers, take.inputs)
        character = basis if config.settings.strategy in SAMPLES_CHARACTER else Target(
            basis.shape_names, basis.lower, basis.upper)
        solve(SolveRequest(character=character, settings=config.settings, inputs=take.inputs, markers=take.markers,
                           controls=config.controls or None))
        return "solved"
    except FacecapError as exc:
        return f"error: {exc}"


def test_hostile_config_variants_end_in_a_solve_or_one_line(workspace):
    folder, base, basis = workspace
    rng = random.Random(18)
    protected = [folder / n for n in ("take.csv", "character.blend")]
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in protected}
    outcomes, slowest = {"solved": 0, "error": 0}, 0.0
    for i in range(VARIANTS):
        text = dump(mutate(base, rng))
        t = time.perf_counter()
        try:
            outcome = run_variant(folder, text, basis)
        except Exception as exc:  # noqa: BLE001 - anything else is the bug this test looks for
            pytest.fail(f"variant {i} raised {type(exc).__name__}: {exc}\n{text}")
        slowest = max(slowest, time.perf_counter() - t)
        if outcome.startswith("error"):  # one line per problem (a config's problems come all at once)
            lines = outcome.removeprefix("error: ").splitlines()
            assert len(lines) == 1 or all(line.startswith(str(folder)) for line in lines), \
                f"variant {i}: several lines that are not each a problem of the file\n{outcome}"
            assert all(0 < len(line) < 1200 for line in lines), f"variant {i}: not one line per problem\n{outcome}"
        outcomes[outcome.split(":")[0]] += 1
    print(f"{VARIANTS} variants: {outcomes}, slowest {slowest:.2f} s")
    assert {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in protected} == before
    assert outcomes["solved"] >= 20 and outcomes["error"] >= VARIANTS // 2  # both paths are exercised
    assert slowest < 30  # nothing runs without bound
    assert not np.any([p.name.startswith(".") for p in folder.rglob("*")])  # no temporary left behind
