"""Static segmentation, pose labels and 360° rotation detection.

Truth: synthetic records with injected holds/rotations, and imucal's hand-annotated example
session (example_ferraris_session_list.json) for real data.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from apmcal.core.errors import ApmcalError
from apmcal.preprocessing.rotations import find_rotations
from apmcal.preprocessing.static import ARDUPILOT_FACE, find_static_segments, label_poses, pose_of

G = 9.80665
IMUCAL_FS = 102.4   # ../shared/data/README.md


def _hold_then_move(t, still_spans, rng, acc0=(0, 0, -G), noise=0.02, move=1.5):
    """acc/gyr with white noise everywhere and a strong wobble outside ``still_spans`` [s]."""
    acc = np.tile(np.asarray(acc0, float), (t.size, 1)) + rng.normal(0, noise, (t.size, 3))
    gyr = rng.normal(0, 0.003, (t.size, 3))
    moving = np.ones(t.size, bool)
    for a, b in still_spans:
        moving[(t >= a) & (t <= b)] = False
    wob = np.sin(2 * np.pi * 1.3 * t)[:, None] * np.array([move, -move, 0.5 * move])
    acc[moving] += wob[moving]
    gyr[moving] += 0.5 * wob[moving]
    return acc, gyr


def test_segments_found_on_irregular_sampling():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.005, 0.015, 6000))           # ~100 Hz, ±50 % jitter
    spans = [(5.0, 15.0), (20.0, 23.0), (30.0, 31.0), (40.0, 55.0)]
    acc, gyr = _hold_then_move(t, spans, rng)
    segs = find_static_segments(t, acc, gyr, min_duration=2.0)
    # the 1 s hold is shorter than min_duration; the rest are found, inside their true spans,
    # and cover them up to about one window (0.5 s) at each end
    kept = [s for s in spans if s[1] - s[0] >= 2.0 and s[1] < t[-1]]
    assert len(segs) == len(kept)
    for seg, (a, b) in zip(segs, kept):
        assert a - 0.02 <= seg.start and seg.end <= b + 0.02
        assert seg.start - a < 0.6 and b - seg.end < 0.6
        assert seg.pose == "z_a" and seg.face == "level"
        np.testing.assert_allclose(seg.gravity_dir, [0, 0, 1], atol=0.02)   # gravity along +z (down)
        np.testing.assert_allclose(seg.up_axis, [0, 0, -1], atol=0.02)


def test_min_duration_and_threshold_options():
    rng = np.random.default_rng(1)
    t = np.arange(0, 60, 0.01)
    acc, gyr = _hold_then_move(t, [(5, 15), (20, 23)], rng)
    assert len(find_static_segments(t, acc, gyr, min_duration=5.0)) == 1
    assert find_static_segments(t, acc, gyr, threshold=(1e-6, 1e-6)) == []


def test_two_hertz_quantised_telemetry():
    """RAW_IMU at 2 Hz, integer mG: noise below one step (ardupilot-facts.md)."""
    rng = np.random.default_rng(2)
    t = np.arange(0, 120, 0.5) + rng.uniform(-0.05, 0.05, 240)
    acc, gyr = _hold_then_move(t, [(10, 40), (60, 100)], rng, acc0=(0, 0, -1000.0), noise=0.3,
                               move=300.0)
    segs = find_static_segments(t, np.round(acc), np.round(gyr * 1000), min_duration=10.0)
    assert len(segs) == 2
    assert segs[0].start >= 9.9 and segs[0].end <= 40.1 and segs[0].duration > 25
    assert segs[1].start >= 59.9 and segs[1].end <= 100.1 and segs[1].duration > 35


@pytest.mark.parametrize("acc, pose, face", [
    ((0, 0, -G), "z_a", "level"),       # ardupilot-facts.md "Frames and signs"
    ((-G, 0, 0), "x_a", "nosedown"),
    ((G, 0, 0), "x_p", "noseup"),
    ((0, G, 0), "y_p", "left"),
    ((0, -G, 0), "y_a", "right"),
    ((0, 0, G), "z_p", "back"),
])
def test_pose_labels_follow_ardupilot_signs(acc, pose, face):
    name, tilt = pose_of(np.array(acc) + 0.3)        # small offset: still that face
    assert name == pose and ARDUPILOT_FACE[name] == face and tilt < 5


def test_tilted_hold_has_no_label():
    tilt = np.radians(40)
    name, deg = pose_of(G * np.array([np.sin(tilt), 0, -np.cos(tilt)]))
    assert name is None and deg == pytest.approx(40)
    name, deg = pose_of(G * np.array([np.sin(np.radians(20)), 0, -np.cos(np.radians(20))]))
    assert name == "z_a" and deg == pytest.approx(20)


def test_bad_input_raises():
    with pytest.raises(ApmcalError):
        find_static_segments(np.arange(10.0), np.zeros((10, 2)))
    with pytest.raises(ApmcalError):
        find_static_segments(np.r_[0, 2, 1.0, 3, 4], np.zeros((5, 3)))


def test_four_quarter_turns_grouped_into_one_full_turn():
    """[Oppong] §3.1: 360° about z in 4 × 90° steps, a hold after each; then one 90° about x."""
    fs, rate = 100.0, np.radians(90.0)          # 1 s per quarter turn
    plan = [("hold", 4)] + [("z", 1), ("hold", 3)] * 4 + [("x", 1), ("hold", 4)]
    gyr_parts = []
    for kind, sec in plan:
        n = int(sec * fs)
        w = np.zeros((n, 3))
        if kind != "hold":
            w[:, "xyz".index(kind)] = -rate      # clockwise, as imucal expects (−360°)
        gyr_parts.append(w)
    gyr = np.vstack(gyr_parts)
    t = np.arange(gyr.shape[0]) / fs
    rng = np.random.default_rng(3)
    bias = np.array([0.01, -0.02, 0.005])
    gyr_meas = gyr + bias + rng.normal(0, 0.002, gyr.shape)
    acc = np.tile([0.0, 0.0, G], (t.size, 1)) + rng.normal(0, 0.01, gyr.shape)
    segs = find_static_segments(t, acc, gyr_meas, min_duration=1.5)
    assert len(segs) == 6
    rots = find_rotations(t, gyr_meas, segs)
    assert [r.axis_name for r in rots] == ["z", "x"]
    z, x = rots
    assert z.n_steps == 4 and z.angle_deg == pytest.approx(-360, abs=1.0) and z.is_full_turn()
    assert x.n_steps == 1 and x.angle_deg == pytest.approx(-90, abs=1.0) and not x.is_full_turn()
    assert 4.0 - 0.6 < z.start <= 4.0 and 17.0 <= z.end < 17.6     # last quarter ends at 17 s


@pytest.fixture
def imucal_session(shared_data):
    d = pd.read_csv(shared_data / "imucal" / "example_ferraris_session.csv")
    sections = json.loads((shared_data / "imucal" / "example_ferraris_session_list.json").read_text())
    t = d["n_samples"].to_numpy() / IMUCAL_FS
    acc = d[["acc_x", "acc_y", "acc_z"]].to_numpy()
    gyr = np.radians(d[["gyr_x", "gyr_y", "gyr_z"]].to_numpy())     # deg/s -> rad/s
    return t, acc, gyr, sections


def test_imucal_session_holds_match_annotation(imucal_session):
    t, acc, gyr, sections = imucal_session
    segs = find_static_segments(t, acc, gyr)
    for name in ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a"):
        lo, hi = sections[name]["start"], sections[name]["end"]
        hits = [s for s in segs if s.i0 <= lo and hi <= s.i1]
        assert len(hits) == 1, name                # the hand-annotated hold lies in one segment...
        assert hits[0].pose == name                # ...labelled with the same name
    poses = label_poses(segs)
    assert sorted(poses) == sorted(["x_p", "x_a", "y_p", "y_a", "z_p", "z_a"])
    for name, seg in poses.items():
        assert seg.pose == name and seg.duration > 5.0
        # no annotated rotation overlaps a chosen hold
        for rot in ("x_rot", "y_rot", "z_rot"):
            assert seg.i1 <= sections[rot]["start"] or seg.i0 >= sections[rot]["end"]


def test_imucal_session_full_turns(imucal_session):
    t, acc, gyr, sections = imucal_session
    segs = find_static_segments(t, acc, gyr)
    full = [r for r in find_rotations(t, gyr, segs) if r.is_full_turn()]
    assert [r.axis_name for r in full] == ["x", "y", "z"]
    for r in full:
        sec = sections[r.axis_name + "_rot"]
        assert r.i0 <= sec["start"] and sec["end"] <= r.i1     # contains the annotated rotation
        assert (r.i1 - r.i0) < 1.5 * (sec["end"] - sec["start"])
        assert abs(r.angle_deg + 360) < 15                    # clockwise: −360° (imucal)
        assert r.off_axis_deg < 2.0
        assert r.pose == r.axis_name + "_p"                   # turned about the up axis


def _level_hold(t, rng, noise=0.02):
    acc = np.tile([0.0, 0.0, -G], (t.size, 1)) + rng.normal(0, noise, (t.size, 3))
    gyr = rng.normal(0, 0.003, (t.size, 3))
    return acc, gyr


def test_bump_inside_a_hold_is_bridged_and_excluded():
    """A 2 s knock (±0.6 m/s², no net turn) splits a 60 s hold; the merge joins it back."""
    rng = np.random.default_rng(4)
    t = np.arange(0, 60, 0.01)
    acc, gyr = _level_hold(t, rng)
    bump = (t >= 30) & (t < 32)
    acc[bump] += 0.6 * np.sin(2 * np.pi * 7 * t[bump])[:, None] * [1, -1, 0.5]
    gyr[bump] += 0.05 * np.sin(2 * np.pi * 7 * t[bump])[:, None]      # returns to where it was
    split = find_static_segments(t, acc, gyr, merge_gap=0.0)
    assert len(split) == 2
    (seg,) = find_static_segments(t, acc, gyr)
    assert seg.duration > 59.0
    assert 200 <= seg.n_excluded <= 300 and seg.n == seg.i1 - seg.i0 - seg.n_excluded
    assert not np.any(bump[seg.kept()])                                # knock left out
    np.testing.assert_allclose(seg.acc_mean, [0, 0, -G], atol=0.005)
    assert np.all(seg.acc_std < 0.03)


def test_tilt_change_or_long_gap_is_not_merged():
    rng = np.random.default_rng(5)
    t = np.arange(0, 60, 0.01)
    acc, gyr = _level_hold(t, rng)
    # tilt by 3° about x during a 1 s move at 30 s: mean specific force differs by 3° > 2°
    tilt = np.radians(3.0)
    after = t >= 31
    acc[after] = (np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)],
                            [0, np.sin(tilt), np.cos(tilt)]]) @ acc[after].T).T
    move = (t >= 30) & (t < 31)
    acc[move] += rng.normal(0, 1.0, (move.sum(), 3))
    gyr[move] += tilt                                                  # rad/s for 1 s
    assert len(find_static_segments(t, acc, gyr)) == 2
    # a 20 s logging hole (no samples) longer than merge_gap splits an unchanged hold
    t2 = np.where(t >= 30, t + 20.0, t)
    acc2, gyr2 = _level_hold(t2, rng)
    segs = find_static_segments(t2, acc2, gyr2)
    assert len(segs) == 2 and segs[0].end < 30 and segs[1].start >= 50
    assert len(find_static_segments(t2, acc2, gyr2, merge_gap=30.0)) == 1


def test_fast_on_100k_samples():
    import time
    rng = np.random.default_rng(6)
    t = np.arange(100_000) / 1000.0                                    # 1 kHz, 100 s
    acc, gyr = _hold_then_move(t, [(5, 30), (40, 70), (80, 95)], rng)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        segs = find_static_segments(t, acc, gyr)
        best = min(best, time.perf_counter() - t0)
    assert len(segs) == 3
    assert best < 0.5
