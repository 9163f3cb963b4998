"""calibration.bench and ``weldcell bench calibration`` (a short run; the full benchmark is the CLI)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from calibration.bench import METHODS, BenchConfig, run_bench, run_trial, target_failures
from calibration.errors import CalibrationError


def test_trial_is_deterministic_and_accurate():
    config = BenchConfig(seed=3)
    a = run_trial(15, 0, config=config)
    b = run_trial(15, 0, config=config)
    assert a.errors == b.errors
    assert set(a.errors) == set(METHODS)
    t_m, r_rad = a.errors["refined"]
    assert t_m < 1e-3 and np.degrees(r_rad) < 0.1
    assert run_trial(15, 1, config=config).errors != a.errors


def test_report_shape():
    report = run_bench(BenchConfig(pose_counts=(8,), trials=1))
    assert list(report) == ["8"]
    assert list(report["8"]) == list(METHODS)
    for errs in report["8"].values():
        assert set(errs) == {"translation_mm", "rotation_deg"}
        assert errs["translation_mm"] is not None and errs["translation_mm"] > 0
        assert errs["rotation_deg"] is not None and errs["rotation_deg"] > 0


def test_target_check():
    good = {
        "15": {
            "refined": {"translation_mm": 0.2, "rotation_deg": 0.03},
            "tsai": {"translation_mm": 0.5, "rotation_deg": 0.06},
            "park": {"translation_mm": 0.4, "rotation_deg": 0.04},
        }
    }
    assert target_failures(good) == []
    bad = json.loads(json.dumps(good))
    bad["15"]["refined"]["rotation_deg"] = 0.045
    assert target_failures(bad) == ["park (0.400 mm, 0.0400 deg) is not worse than refined"]
    bad["15"]["refined"]["translation_mm"] = 0.6
    assert "refined translation 0.600 mm > 0.5 mm" in target_failures(bad)
    assert target_failures({"8": good["15"]}) == ["no result for 15 poses"]


def test_config_is_checked():
    with pytest.raises(CalibrationError, match="trials must be >= 1"):
        BenchConfig(trials=0)


def test_cli_prints_the_json_report(capsys):
    from cell.commands import bench

    parser = argparse.ArgumentParser(prog="weldcell")
    sub = parser.add_subparsers(dest="command")
    bench.add_parser(sub)
    args = parser.parse_args(["bench", "calibration", "--json", "--trials", "1", "--poses", "8", "--seed", "2"])
    assert args.func(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert list(report) == ["8"]
    assert list(report["8"]) == list(METHODS)
    assert report == run_bench(BenchConfig(pose_counts=(8,), trials=1, seed=2))
    with pytest.raises(SystemExit):
        parser.parse_args(["bench", "calibration", "--poses", "2"])


def test_every_closed_form_result_of_the_bench_comes_from_cv2_calibrate_hand_eye(monkeypatch):
    import cv2

    from calibration.axxb import LinearMethod

    calls: list[int] = []
    real = cv2.calibrateHandEye

    def counting(*args, **kwargs):
        calls.append(kwargs["method"])
        return real(*args, **kwargs)

    monkeypatch.setattr(cv2, "calibrateHandEye", counting)
    trial = run_trial(8, 0, config=BenchConfig(seed=1))
    assert sorted(calls) == sorted(m.opencv_flag for m in LinearMethod)  # each of the five methods, once
    assert all(np.all(np.isfinite(e)) for e in trial.errors.values())


def test_a_trial_on_rendered_images_measures_every_board_with_the_detector(monkeypatch):
    import calibration.bench as bench_module
    from sim_fakes.board_render import BoardRenderer

    detected = []
    real = bench_module.detect_board

    def counting(image, **kwargs):
        detected.append(image.shape)
        return real(image, **kwargs)

    monkeypatch.setattr(bench_module, "detect_board", counting)
    trial = run_trial(8, 0, config=BenchConfig(seed=4), render=BoardRenderer())
    assert detected == [(800, 1280)] * 8  # every view rendered at the bench camera's size and detected
    # the same figures as `weldcell bench calibration --images --trials 1 --poses 8 --seed 4` (0.0633 mm, 0.0202 deg)
    t_m, r_rad = trial.errors["refined"]
    assert round(t_m * 1000.0, 4) == 0.0633 and round(float(np.degrees(r_rad)), 5) == 0.02023
