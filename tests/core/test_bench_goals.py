"""``python -m facecap bench`` says whether each case met its goal (issue 40: "1.258 s ... goal < 1 s" was printed
without saying it was missed)."""

import pytest

from facecap.solvers.tools.bench.bench import goal_verdict


@pytest.mark.parametrize("goal, seconds, ratio, said", [
    (">= 50x and < 1 s", 1.258, 129.0, "goal >= 50x and < 1 s: MISSED (1.258 s is not under 1 s)"),
    (">= 50x and < 1 s", 0.85, 129.0, "goal >= 50x and < 1 s: met"),
    (">= 50x and < 1 s", 0.85, 31.0, "goal >= 50x and < 1 s: MISSED (31x is below 50x)"),
    ("< 15 s", 16.2, None, "goal < 15 s: MISSED (16.200 s is not under 15 s)"),
    ("well under 1 s", 0.31, 9.0, "goal well under 1 s: met"),
    (">= 3x vs sequential retarget runs", 40.0, 2.1, "goal >= 3x vs sequential retarget runs: MISSED (2.1x is below 3x)"),
    ("work grows with the take (10x the frames: about 10x the time)", 1.0, 396.0,
     "goal work grows with the take (10x the frames: about 10x the time)"),  # words: shown, not judged
])
def test_goal_verdict(goal, seconds, ratio, said):
    assert goal_verdict({"goal": goal, "seconds": seconds, "ratio": ratio}) == said
