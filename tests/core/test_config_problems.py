"""A config's mistakes come all at once, one line each, with a "did you mean" for misspelt sections, keys
and values: take configs (retarget), track configs and batch files alike."""

from pathlib import Path

import pytest

from facecap.solvers.config import load_take_config
from facecap.solvers.config.batch import collect_takes
from facecap.solvers.errors import ConfigError, ConfigProblems
from facecap.solvers.errors import suggest
from facecap.solvers.video.cli import load_track_config

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"


def problems(fn, path):
    with pytest.raises(ConfigError) as info:
        fn(path)
    lines = str(info.value).splitlines()
    assert all(line.startswith(str(path)) for line in lines), lines  # each line names the file
    return lines


def test_five_mistakes_in_a_take_config_are_five_lines(tmp_path):
    path = tmp_path / "take.toml"
    path.write_text(f'[target]\nblend = "{SAMPLES / "character.blend"}"\n'   # 1: object missing
                    '[source]\nmarkers = "take.csv"\nfps = -60\n'               # 2: fps out of range
                    '[stabilize]\nmarkers = ["a", "b", "c"]\n'                  # 3: [stabilize]
                    '[neutral]\nframes = [1, 30]\n'
                    '[solve]\nstrategy = "geometrc"\nregularisaton = 0.1\n'     # 4, 5: a value, a key
                    '[output]\nweights = "out/w.csv"\n')
    lines = problems(load_take_config, path)
    assert len(lines) == 5, lines
    text = "\n".join(lines)
    assert "unknown section [stabilize] (did you mean 'stabilise'?)" in text
    assert "[solve.strategy] expected one of " in text and "got 'geometrc' (did you mean 'geometric'?)" in text
    assert "[solve.regularisaton] unknown key (did you mean 'regularisation'?)" in text
    assert "[source.fps] expected a number > 0 and <= 10000; got -60" in text
    assert "[target.object] missing required key" in text
    assert "[stabilise.markers] missing" not in text  # the misspelt section is the one mistake


def test_one_mistake_is_one_plain_config_error(tmp_path):
    path = tmp_path / "take.toml"
    path.write_text('[target]\nobject = "Face"\n[source]\nmarkers = "take.csv"\n[stabilise]\nmarkers = "auto"\n'
                    '[neutral]\nframes = [1, 30]\n[output]\nweights = "w.csv"\nreprot = "r.json"\n')
    with pytest.raises(ConfigError) as info:
        load_take_config(path)
    assert not isinstance(info.value, ConfigProblems) and info.value.key == "output.reprot"
    assert "did you mean 'report'?" in str(info.value)


def test_five_mistakes_in_a_track_config_are_five_lines(tmp_path):
    path = tmp_path / "track.toml"
    path.write_text('[source]\nvideo = "clip.avi"\nfps = "x"\n'            # 1: a number expected
                    '[tracking]\npoints = "p.csv"\nmethod = "farnback"\n'   # 2: a value
                    'win_sise = 21\nlevels = -5\n'                          # 3: a key, 4: a range
                    '[outptu]\nreport = "r.json"\n')                        # 5: a section (and markers missing)
    lines = problems(load_track_config, path)
    text = "\n".join(lines)
    assert len(lines) == 5, lines
    assert "unknown section [outptu] (did you mean 'output'?)" in text
    assert "[tracking.method] expected one of lk, dis, farneback, tvl1, landmarks; got 'farnback' (did you mean " \
           "'farneback'?)" in text
    assert "[tracking.win_sise] unknown key (did you mean 'win_size'?)" in text
    assert "[tracking.levels] expected an integer >= 0 and <= 10; got -5" in text
    assert "[source.fps] expected a number; got 'x'" in text


def test_mistakes_in_a_batch_file_come_at_once(tmp_path):
    path = tmp_path / "batch.toml"
    (tmp_path / "takes").mkdir()
    (tmp_path / "takes" / "a.toml").write_text('[source]\nmarkers = "a.csv"\n')
    path.write_text('[batch]\ntakes = ["takes/"]\ntake = 1\n'                      # 1: a key
                    '[defaults.solv]\nstrategy = "geometric"\n'                   # 2: a section
                    '[defaults.solve]\nstrategy = "paralel"\n'                    # 3: a value
                    '[defaults.source]\nunits = "inch"\nfps = 1e9\n')             # 4, 5: a value, a range
    lines = problems(lambda p: collect_takes([p]), path)
    text = "\n".join(lines)
    assert len(lines) == 5, lines
    assert "[batch.take] unknown key (did you mean 'takes'?)" in text
    assert "unknown section [defaults.solv] (did you mean 'solve'?)" in text
    assert "(did you mean 'parallel'?)" in text and "[defaults.source.fps] expected a number > 0" in text
    assert "[defaults.source.units] expected one of m, cm, mm, bu, px; got 'inch'" in text


@pytest.mark.parametrize("word, candidates, hint", [
    ("stabilize", ("stabilise", "neutral"), " (did you mean 'stabilise'?)"),
    ("OUTPUT", ("output",), " (did you mean 'output'?)"),
    ("zzz", ("output", "source"), ""),
    (5, ("output",), ""),
])
def test_suggestions(word, candidates, hint):
    assert suggest(word, candidates) == hint


def test_every_number_of_every_config_has_an_upper_bound():
    """A typo of a few zeros (or 1e300) is refused by the checks, not met later by an allocation or an
    overflow: every numeric option, of take and track configs, has an upper bound, shown in the docs."""
    from facecap.solvers.options import OPTIONS
    from facecap.solvers.video.cli import TRACK_OPTIONS

    numeric = [o for o in OPTIONS + TRACK_OPTIONS
               if {"int", "float", "floats"} & set(o.kind if isinstance(o.kind, tuple) else (o.kind,))]
    assert len(numeric) > 40
    unbounded = [o.name for o in numeric if o.high is None and o.name != "source.frame_offset"]
    assert not unbounded, unbounded
    assert all("<=" in o.range_text() for o in numeric if o.high is not None)
