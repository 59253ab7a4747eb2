"""baselines/render_gif.py: a short GIF of the passivity policy; bad input exits 2 before any work."""

from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import pytest  # noqa: E402
from PIL import Image  # noqa: E402

from softpvtol_gym.baselines.commands.render_gif import main


def test_gif_of_the_passivity_policy(tmp_path, capsys):
    out = tmp_path / "a.gif"
    assert main(["--policy", "passivity", "--task", "hover", "--seconds", "0.5", "--fps", "20", "--scale", "0.2",
                 "--out", str(out)]) == 0
    im = Image.open(out)
    assert im.size == (120, 90) and im.n_frames == 10  # 0.5 s at 20 frames/s
    assert "passivity (bounded)" in capsys.readouterr().out


@pytest.mark.parametrize("argv, match", [
    (["--fps", "30"], "--fps must divide 100"),
    (["--out", "{tmp}/a.png"], "must name a .gif"),
    (["--fps", "0"], "must be >= 1"),
    (["--seconds", "-1"], "--seconds"),
    (["--task", "loop"], "invalid choice"),
])
def test_bad_input_exits_2(tmp_path, capsys, argv, match):
    base = {"--policy": "passivity", "--out": str(tmp_path / "a.gif"), "--seconds": "0.1"}
    for k, v in zip(argv[::2], argv[1::2]):
        base[k] = v.replace("{tmp}", str(tmp_path))
    with pytest.raises(SystemExit) as exc:
        main([x for kv in base.items() for x in kv])
    assert exc.value.code == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "a.gif").exists()
