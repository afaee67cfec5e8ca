"""Output paths that cannot be written (a folder in place of a file, a file in place of a folder):
refused naming the path, before any work and before any other output is replaced."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vid2haircut.cli import main

KF = "keyframes.json"


def test_image_writer_names_the_file_for_an_unknown_format(tmp_path):
    from vid2haircut.io.atomic import write_image

    with pytest.raises(OSError, match="x.txt: OpenCV could not encode"):
        write_image(tmp_path / "x.txt", np.zeros((4, 4, 3), np.uint8))
    assert not list(tmp_path.iterdir())


def test_a_folder_in_place_of_an_output_is_refused_before_writing(tmp_path):
    """export writes five files: a folder where the fourth should go is found before the first is
    replaced; an atomic write onto a folder names the output, not its temporary file."""
    from vid2haircut.export.export import export_hairstyle
    from vid2haircut.io.atomic import write_text
    from vid2haircut.strands import StrandSet

    rng = np.random.default_rng(0)
    strands = StrandSet(points=rng.normal(size=(3, 5, 3)).astype(np.float32))
    out = tmp_path / "out"
    (out / "hair.ply").mkdir(parents=True)
    (out / "hair.data").write_bytes(b"old")
    with pytest.raises(IsADirectoryError, match=r"hair\.ply: is a folder"):
        export_hairstyle(strands, out)
    assert (out / "hair.data").read_bytes() == b"old" and not (out / "hair.usda").exists()
    (tmp_path / "f.json").mkdir()
    with pytest.raises(IsADirectoryError, match=r"f\.json: is a folder"):
        write_text(tmp_path / "f.json", "{}")
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_targets_are_not_left_mixed_by_a_folder_in_place_of_an_output(tmp_path):
    from vid2haircut.front.targets.build import FrameTargets, write_targets

    z = np.zeros((8, 8), np.float32)
    targets = [FrameTargets(t, np.zeros((8, 8, 3), np.uint8), z, z, z, z, z > 0, "file") for t in (3, 7)]
    (tmp_path / "orientation_00007.png").mkdir()
    with pytest.raises(IsADirectoryError, match=r"orientation_00007\.png: is a folder"):
        write_targets(tmp_path, targets, {})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["orientation_00007.png"]


def test_an_output_under_a_file_names_it(tmp_path):
    from vid2haircut.io.atomic import write_json

    (tmp_path / "out").write_text("a file")
    with pytest.raises(NotADirectoryError, match=r"out: is a file, cannot hold the output .*out/sub/x\.json"):
        write_json(tmp_path / "out" / "sub" / "x.json", {})
    assert (tmp_path / "out").read_text() == "a file"


def test_an_output_folder_that_is_a_file_is_refused_before_any_work(tmp_path, capsys):
    (tmp_path / "out").write_text("a file")
    for argv in (["keyframes", "--root", "R", "--subject", "S", "--seq", "Q", "--out", str(tmp_path / "out")],
                 ["head", "export", str(tmp_path / "out" / "head")]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
        assert f"{tmp_path / 'out'}: is a file, cannot hold the output folder" in capsys.readouterr().err
    assert (tmp_path / "out").read_text() == "a file"


def test_front_stages_check_their_outputs_before_any_work(tmp_path):
    """keyframes and fit_head write two files each; a folder where the second goes is found before
    the sequence is read (it had been found after the work, with the first file already replaced)."""
    from vid2haircut.front.stages import run_fit_head, run_keyframes

    (tmp_path / "kf" / "keyframes.json").mkdir(parents=True)
    with pytest.raises(IsADirectoryError, match=r"keyframes\.json: is a folder"):
        run_keyframes(tmp_path / "no_such_root", "s", "q", tmp_path / "kf")
    (tmp_path / KF).write_text(json.dumps({"frames": [1], "reference": 1, "serial": "c"}))
    (tmp_path / "head" / "head.npz").mkdir(parents=True)
    with pytest.raises(IsADirectoryError, match=r"head\.npz: is a folder"):
        run_fit_head(tmp_path / "no_such_root", "s", "q", tmp_path / KF, tmp_path / "head")
    assert sorted(p.name for p in tmp_path.rglob("*.png")) == []
