"""Bad option values of the command line: refused before any work, naming the option (or the value)."""

from __future__ import annotations

import re

import pytest

from vid2haircut.cli import main


@pytest.mark.parametrize("argv, message", [
    (["targets", "--root", "R", "--subject", "S", "--seq", "Q", "--keyframes", "k", "--head", "h", "--out", "o",
      "--device", "banana"], "not a torch device"),
    (["keyframes", "--root", "R", "--subject", "S", "--seq", "Q", "--out", "o", "--frontal-tolerance", "-10"],
     "expected a finite number >= 0"),
    (["evaluate", "--pred", "p", "--gt", "g", "--out", "o", "--max-points", "-5"], "expected a whole number >= 0"),
    (["evaluate", "--pred", "p", "--gt", "g", "--out", "o", "--seed", "-1"], "expected a whole number >= 0"),
    (["figures", "turntable", "--strands", "s", "--out", "x.txt"], "the image format comes from the suffix"),
    (["figures", "turntable", "--strands", "s", "--out", "x.png", "--max-strands", "-3"], "whole number >= 0"),
    (["head", "export", "d", "--res", "100000"], "in [1, 4096]"),
    (["keyframes", "--root", "R", "--subject", "S", "--seq", "Q", "--out", "o", "--max-candidates", "0"],
     "expected a whole number >= 1"),
    (["keyframes", "--root", "R", "--subject", "S", "--seq", "Q", "--out", "o", "--blur-ratio", "nan"],
     "expected a number in [0, 1]"),
    (["keyframes", "--root", "R", "--subject", "S", "--seq", "Q", "--out", "o", "--still-frames", "-5"],
     "expected a whole number >= 0"),
    (["fit_head", "--root", "R", "--subject", "S", "--seq", "Q", "--out", "o", "--keyframes", "k",
      "--min-frames", "-3"], "expected a whole number >= 1"),
    (["figures", "turntable", "--strands", "s", "--out", "x.png", "--size", "100000"], "in [16, 4096]"),
    (["export", "--strands", "s", "--out-dir", "o", "--stem", "../escape"], "without a folder part"),
])
def test_bad_option_values_are_refused_before_any_work(argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert message in err and argv[-2] in err  # argparse names the option


def test_cuda_device_needs_cuda():
    import argparse

    import torch

    from vid2haircut.cli import argtypes

    assert argtypes.device("cpu") == "cpu"
    if not torch.cuda.is_available():
        with pytest.raises(argparse.ArgumentTypeError, match="CUDA is not available"):
            argtypes.device("cuda:7")
    else:
        with pytest.raises(argparse.ArgumentTypeError, match="CUDA device"):
            argtypes.device(f"cuda:{torch.cuda.device_count()}")


@pytest.mark.parametrize("option, value, message", [
    ("--landmark-noise", "-1", "landmark_noise_px and color_jitter must be >= 0"),
    ("--landmark-noise", "nan", "landmark_noise_px must be finite"),
    ("--yaw-max", "nan", "yaw_max_deg must be finite"),
    ("--yaw-max", "200", r"yaw_max_deg must be in \[0, 90\]"),
    ("--sway-max", "nan", "sway_max_m must be finite"),
    ("--serial", "a/b", "serial must be letters, digits"),
])
def test_synthesize_overwrite_keeps_the_old_sequence_on_a_bad_value(tmp_path, caplog, option, value, message):
    """--overwrite replaces a sequence only once every value is checked (a bad one had deleted the
    old folder and left a half-written one; NaN values had run through)."""
    seq = tmp_path / "subj" / "sequences" / "SEQ"
    seq.mkdir(parents=True)
    (seq / "old.txt").write_text("keep")
    argv = ["synthesize", "--root", str(tmp_path), "--subject", "subj", "--seq", "SEQ", "--frames", "2",
            "--size", "32", "--strands", "4", "--points", "4", "--overwrite", option, value]
    assert main(argv) == 2
    assert re.search(message, caplog.text), caplog.text
    assert [p.name for p in seq.iterdir()] == ["old.txt"]
    assert not (tmp_path / "subj" / "calibration").exists()
