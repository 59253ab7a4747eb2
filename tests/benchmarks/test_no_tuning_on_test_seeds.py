"""Nothing is tuned on the episodes the leaderboard reports: the benchmark and baseline scripts name a seed of the
test range (1,000,000 + i, ``EVAL_SEED_OFFSET``) only where they report or time those episodes, never where they
sweep, tune or choose (those use the tuning range, ``TUNING_SEED`` = 3,000,000 + i).

Scanned: every module under ``benchmarks/`` and ``softpvtol_gym/baselines/``, token by token (code only, not its
docstrings or comments). A statement uses a test-range seed when it names ``EVAL_SEED_OFFSET`` (imports aside), or
holds an integer in [1,000,000, 2,000,000) beside a name or string that says "seed". The modules allowed to are
listed in :data:`REPORTS`, each with what it does with those episodes.
"""

from __future__ import annotations

import io
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCANNED = sorted([*(ROOT / "benchmarks").glob("*.py"), *(ROOT / "softpvtol_gym" / "baselines").rglob("*.py")])
TEST_RANGE = range(1_000_000, 2_000_000)
#: module -> why it may name the test range: it reports or times the test episodes and chooses nothing on them
REPORTS = {
    "softpvtol_gym/baselines/evaluation.py": "defines the test range",
    "softpvtol_gym/baselines/leaderboard/spec.py": "checks that a spec's test episodes lie in the test range",
    "softpvtol_gym/baselines/commands/evaluate.py": "softpvtol evaluate: a held-out report of one policy",
    "softpvtol_gym/baselines/commands/train.py": "train.py's closing comparison with the passivity controller",
    "softpvtol_gym/baselines/training/loop.py": "the learning curve's periodic evaluation (never selects a model)",
    "softpvtol_gym/baselines/commands/figures.py": "figures of a test episode",
    "softpvtol_gym/baselines/figures/tracking.py": "figures of the leaderboard's test episodes",
    "softpvtol_gym/baselines/commands/render_gif.py": "a GIF of a test episode",
    "benchmarks/per_robot_compute.py": "times the leaderboard's per-robot compute pass on its test episode",
    "benchmarks/ppo_speed.py": "training speed; its held-out evaluation is train.py's",
    "benchmarks/tracking_evaluation.py": "reports trained runs on the test episodes",
    "benchmarks/mpc_quality.py": "docs/control.md's table: the MPC on one test episode per tier",
}


def lines_using_test_seeds(source: str) -> list[int]:
    """The lines of ``source`` (Python) whose statement uses a test-range seed (module docstring)."""
    found, statement = [], []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type in (tokenize.NEWLINE, tokenize.ENDMARKER):
            names = [t.string for t in statement if t.type == tokenize.NAME]
            texts = names + [t.string for t in statement if t.type == tokenize.STRING]
            numbers = [t for t in statement if t.type == tokenize.NUMBER and t.string.replace("_", "").isdigit()
                       and int(t.string.replace("_", "")) in TEST_RANGE]
            is_import = names[:1] in (["import"], ["from"])
            if ("EVAL_SEED_OFFSET" in names and not is_import) or (
                    numbers and any("seed" in t.lower() for t in texts)):
                found.append(statement[0].start[0])
            statement = []
        elif tok.type not in (tokenize.COMMENT, tokenize.NL, tokenize.INDENT, tokenize.DEDENT):
            statement.append(tok)
    return found


@pytest.mark.parametrize("path", SCANNED, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_script_tunes_on_test_episodes(path):
    rel = str(path.relative_to(ROOT))
    lines = lines_using_test_seeds(path.read_text(encoding="utf-8"))
    if rel in REPORTS:
        return
    assert not lines, (f"{rel} uses a seed of the test range (lines {lines}); sweeps, tunings and choices use the "
                       f"tuning range (softpvtol_gym.baselines.evaluation.TUNING_SEED), or list the module in REPORTS "
                       f"with what it reports")


def test_the_reports_listed_exist_and_the_scan_finds_a_planted_tuning_seed():
    assert all((ROOT / m).is_file() for m in REPORTS)
    assert lines_using_test_seeds('EPISODES, SEED = 5, 1_000_000\n') == [1]
    assert lines_using_test_seeds('ap.add_argument(\n    "--seed",\n    type=int, default=1000000)\n') == [1]
    assert lines_using_test_seeds('run(policy, EVAL_SEED_OFFSET + i)\n') == [1]
    assert lines_using_test_seeds('from x import EVAL_SEED_OFFSET\nTIMESTEPS = 1_000_000\n"""seed 1_000_000"""\n') == []
    assert lines_using_test_seeds('SEED = TUNING_SEED  # not 1_000_000\nX = 2_000_000  # seed\n') == []


def test_the_tuning_scripts_use_the_tuning_range():
    from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, TUNING_SEED
    from softpvtol_gym.baselines.leaderboard.spec import SELECTION_SEED

    assert TUNING_SEED >= SELECTION_SEED + 1_000_000 > EVAL_SEED_OFFSET + 1_000_000
    for script in ("integral_sweep.py", "mpc_tuning.py"):
        assert "TUNING_SEED" in (ROOT / "benchmarks" / script).read_text()
