"""``[output] html`` and ``retarget --html/--truth`` as a TD meets them: the page is one more checked output
(never an input, never another output), and a bad ``--truth`` is one line before any solve."""

import pytest
from test_output_safety import SAMPLES, refused, write_config

from facecap.facecap_addon.headless.headless import preflight
from facecap.facecap_addon.render.review import read_review_truth, review_flags
from facecap.solvers.config import load_take_config
from facecap.solvers.errors import ConfigError, InputFileError


def test_html_is_read_from_the_config_and_overridden_by_the_flag(tmp_path):
    config = load_take_config(write_config(tmp_path, 'html = "out/review.html"'))
    assert config.output_html == tmp_path / "out" / "review.html"
    flagged = review_flags(config, html=str(tmp_path / "elsewhere.html"), truth=str(SAMPLES / "sample_take_weights.csv"))
    assert flagged.output_html == tmp_path / "elsewhere.html"
    assert flagged.truth_path == SAMPLES / "sample_take_weights.csv"
    preflight(flagged)  # an html-only take writes something: accepted


def test_truth_without_a_page_is_refused(tmp_path):
    config = load_take_config(write_config(tmp_path, 'weights = "out/w.csv"'))
    with pytest.raises(ConfigError, match="--truth is shown on the review page: give --html or \\[output\\] html"):
        review_flags(config, truth="truth.csv")


@pytest.mark.parametrize("output, clash", [
    ('html = "take.csv"', r"\[output.html\] is the same file as \[source.markers\]"),
    ('html = "out/x.html"\nweights = "out/x.html"', r"\[output.weights\] and \[output.html\] are the same file"),
])
def test_the_page_never_writes_over_an_input_or_another_output(tmp_path, output, clash):
    refused(write_config(tmp_path, output), clash)


def test_the_page_never_writes_over_the_truth(tmp_path):
    (tmp_path / "truth.csv").write_text("frame,jawOpen\n1,0.5\n")
    config = review_flags(load_take_config(write_config(tmp_path, 'weights = "out/w.csv"')),
                          html=str(tmp_path / "truth.csv"), truth=str(tmp_path / "truth.csv"))
    with pytest.raises(ConfigError, match=r"\[output.html\] is the same file as --truth"):
        preflight(config)
    assert (tmp_path / "truth.csv").read_text() == "frame,jawOpen\n1,0.5\n"


@pytest.mark.parametrize("text, match", [(None, "truth weights file not found"),
                                         ("time,jawOpen\n1,0.5\n", "no frame column"),
                                         ("frame,jawOpen\n1,abc\n", "line 2")])
def test_a_bad_truth_file_is_one_line_naming_it(tmp_path, text, match):
    truth = tmp_path / "truth.csv"
    if text is not None:
        truth.write_text(text)
    config = review_flags(load_take_config(write_config(tmp_path, 'html = "out/r.html"')), truth=str(truth))
    with pytest.raises(InputFileError, match=match) as info:
        read_review_truth(config)
    assert "truth.csv" in str(info.value) and "\n" not in str(info.value)
