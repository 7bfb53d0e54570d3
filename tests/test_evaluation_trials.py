"""Trial runner: pairs carry the right ground truth, trials are pure functions of their seed,
and serial, process-pool and Dask runs give identical rows."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc.errors import UnknownNameError
from sgloc.evaluation import make_pair_source, reproducible_part, run_task, run_trials
from sgloc.evaluation.experiments import ExperimentOptions, make_sweep
from sgloc.evaluation.metrics import correct_matches
from sgloc.geometry import apply


def _sweep(name, dataset, **options):
    return make_sweep(name, dataset, ExperimentOptions(**options))


def _same(rows_a, rows_b):
    """Equal rows: the same keys and values, floats to 1e-9, NaN equal to NaN."""
    a = [reproducible_part(r) for r in rows_a]
    b = [reproducible_part(r) for r in rows_b]
    assert [sorted(x) for x in a] == [sorted(x) for x in b]
    for x, y in zip(a, b, strict=True):
        for k, v in x.items():
            if isinstance(v, float):
                assert np.isclose(v, y[k], rtol=1e-9, atol=1e-9, equal_nan=True), (k, v, y[k])
            else:
                assert v == y[k], (k, v, y[k])


def test_airsim_pair_ground_truth_aligns_the_two_maps():
    src = make_pair_source("airsim-guo")
    p0, p1 = src(0), src(1)
    assert not np.allclose(p0.T_target_query, p1.T_target_query)  # each seed its own pose
    for p in (p0, p1):
        # Under the GT, about 120 cloud1 vertices have a same-class cloud2 vertex within 5 m.
        q = apply(p.T_target_query, p.query.positions)
        d = np.linalg.norm(q[:, None] - p.target.positions[None], axis=2)
        d[p.query.labels[:, None] != p.target.labels[None]] = np.inf
        assert 100 <= (d.min(axis=1) < 5).sum() <= 140
        # ... and under a wrong transform almost none do.
        q_bad = p.query.positions
        d_bad = np.linalg.norm(q_bad[:, None] - p.target.positions[None], axis=2)
        assert (d_bad.min(axis=1) < 5).sum() < 40
    assert np.array_equal(src(0).T_target_query, p0.T_target_query)


def test_object_world_pair_ground_truth(rng):
    p = make_pair_source("object-world", overlap=0.5)(3)
    idx = np.arange(len(p.query))
    # correct_matches of every query vertex with its nearest target under the GT: most correct
    q = apply(p.T_target_query, p.query.positions)
    nn = np.argmin(np.linalg.norm(q[:, None] - p.target.positions[None], axis=2), axis=1)
    ok = correct_matches(p.query.positions, p.target.positions, np.c_[idx, nn], p.T_target_query)
    assert ok.mean() > 0.4


def test_unknown_dataset_and_parameter_are_named():
    with pytest.raises(UnknownNameError, match="nope"):
        make_pair_source("nope")
    with pytest.raises(UnknownNameError, match="overlap"):
        make_pair_source("airsim-guo", overlap=0.3)


def test_graph_folder_pair_source(tmp_path, airsim_graphs):
    q, t = airsim_graphs
    q.save(tmp_path / "query.npz")
    t.save(tmp_path / "target.npz")
    src = make_pair_source(str(tmp_path))
    a = make_pair_source("airsim-guo")(5)
    b = src(5)
    assert np.allclose(a.T_target_query, b.T_target_query)
    assert np.allclose(a.target.positions, b.target.positions)


def test_sweeps_build_the_grid_with_shared_seeds():
    tasks = _sweep("table", "airsim-guo", trials=3, threshold=4.0).tasks()
    assert len(tasks) == 3 * 2 * 3
    assert sorted({t.seed for t in tasks}) == [0, 1, 2]
    cells = {(t.config["descriptor"], t.config["rejection"]) for t in tasks}
    assert len(cells) == 6
    assert all(t.config["ransac"]["threshold"] == 4.0 for t in tasks)
    th = _sweep("threshold", "airsim-guo", trials=2, thresholds=[1, 5, 9], descriptors=["fast"])
    assert sorted({t.config["ransac"]["threshold"] for t in th.tasks()}) == [1.0, 5.0, 9.0]
    ov = _sweep("overlap", "object-world", trials=2, overlaps=[0.2, 0.6]).tasks()
    assert {t.dataset_params["overlap"] for t in ov} == {0.2, 0.6}
    assert {t.tags["overlap"] for t in ov} == {0.2, 0.6}


def test_trial_row_is_scored_and_timed():
    task = _sweep("table", "airsim-guo", trials=1, descriptors=["histogram"]).tasks()
    row = run_task(task[1])  # histogram + neighbor, seed 0
    assert row["rejection"] == "neighbor" and row["seed"] == 0
    assert row["localized"] and not row["failed"]
    assert row["translation_error_m"] < 10
    assert 0 < row["n_final"] <= row["n_survivors"] <= row["n_candidates"]
    assert row["n_correct_final"] <= row["n_correct_survivors"] <= row["n_correct_candidates"]
    assert row["recall"] == pytest.approx(row["n_correct_final"] / row["n_correct_candidates"])
    assert row["precision"] == pytest.approx(row["n_correct_final"] / row["n_final"])
    for stage in ("descriptors", "matching", "rejection", "ransac", "estimation", "total"):
        assert row[f"t_{stage}_ms"] >= 0
    assert row["t_total_ms"] >= row["t_ransac_ms"]


def test_same_seed_same_row_and_different_seed_different_pose():
    tasks = _sweep(
        "table", "airsim-guo", trials=3, descriptors=["random_walk"], rejections=["neighbor"]
    ).tasks()
    a = [run_task(t) for t in tasks]
    b = [run_task(t) for t in tasks]
    _same(a, b)
    errs = {round(r["translation_error_m"], 9) for r in a}
    assert len(errs) == 3  # three seeds, three different pairs


def test_process_pool_equals_serial():
    opts = {"trials": 3, "descriptors": ["histogram"], "dataset_params": {"overlap": 0.4}}
    sweep = _sweep("table", "object-world", **opts)
    tasks = sweep.tasks()
    _same(run_trials(tasks, workers=1), run_trials(tasks, workers=2))


def test_dask_cluster_equals_local():
    distributed = pytest.importorskip("distributed")
    tasks = _sweep("table", "airsim-guo", trials=3, descriptors=["histogram"]).tasks()
    local = run_trials(tasks, workers=1)
    done = []
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        on_dask = run_trials(tasks, scheduler=cluster.scheduler_address, progress=done.append)
    assert sum(done) == len(tasks)
    _same(local, on_dask)


def test_errors_in_the_target_maps_own_frame():
    # object-world pairs are not moved: both error columns agree
    t = _sweep("overlap", "object-world", trials=1, overlaps=[0.6], rejections=["neighbor"]).tasks()
    row = run_task(t[0])
    assert row["translation_error_m"] == pytest.approx(row["translation_error_moved_m"])
    assert row["pair_overlap"] == 0.6
    # airsim pairs are moved by up to 200 m: the moved-frame error adds rotation x shift
    t = _sweep("table", "airsim-guo", trials=4, descriptors=["histogram"]).tasks()
    rows = [run_task(x) for x in t]
    diff = [abs(r["translation_error_m"] - r["translation_error_moved_m"]) for r in rows]
    bound = [np.radians(r["rotation_error_deg"]) * r["pair_initial_translation_m"] for r in rows]
    assert all(d <= b + 1e-6 for d, b in zip(diff, bound, strict=True))


def _near_same_class(p, radius):
    q = apply(p.T_target_query, p.query.positions)
    d = np.linalg.norm(q[:, None] - p.target.positions[None], axis=2)
    d[p.query.labels[:, None] != p.target.labels[None]] = np.inf
    return int((d.min(axis=1) < radius).sum())


def test_kitti00_pairs_ground_truth_and_overlap(data_dir):
    split = make_pair_source("kitti00")(0)
    assert split.info["scans_a"] == "0-800" and split.info["scans_b"] == "3900-4540"
    # the data README: about 80 of B's objects have a same-class object of A within 2 m
    assert _near_same_class(split, 2.0) >= 50
    lo, hi = make_pair_source("kitti00", overlap=0.1), make_pair_source("kitti00", overlap=0.5)
    p_lo, p_hi = lo(0), hi(0)
    assert p_lo.info["overlap"] == pytest.approx(0.1, abs=0.03)
    assert p_hi.info["overlap"] == pytest.approx(0.5, abs=0.05)
    assert _near_same_class(p_hi, 2.0) > _near_same_class(p_lo, 2.0) >= 1


def test_airsim_layout_run_folder_is_a_pair_source(tmp_path):
    from sgloc.evaluation.pairs_sim import AirsimRunPairs
    from sgloc.sim.run import make_synthetic_run

    make_synthetic_run(seed=1, overlap=0.8, width=96, height=54, length=80.0).write(tmp_path)
    src = make_pair_source(str(tmp_path))
    assert isinstance(src, AirsimRunPairs)
    p = src(0)
    assert len(p.query) > 10 and len(p.target) > 10
    # the ground truth brings shared objects together (the moved target alone does not)
    assert _near_same_class(p, 3.0) > 3 * max(1, _near_same_class_no_gt(p, 3.0))


def _near_same_class_no_gt(p, radius):
    d = np.linalg.norm(p.query.positions[:, None] - p.target.positions[None], axis=2)
    d[p.query.labels[:, None] != p.target.labels[None]] = np.inf
    return int((d.min(axis=1) < radius).sum())


def test_timing_repeats_change_no_result():
    sweep = _sweep("table", "airsim-guo", trials=2, descriptors=["fast"])
    once = run_trials(sweep.tasks(), workers=1)
    sweep.repeats = 3
    thrice = run_trials(sweep.tasks(), workers=1)
    _same(once, thrice)
    assert all(r["t_cpu_ms"] > 0 for r in thrice)


def test_cpu_clock_stage_times_add_up_to_at_most_the_calls_cpu_time():
    t = _sweep("table", "airsim-guo", trials=1, descriptors=["histogram"]).tasks()
    row = run_task(t[1])
    stages = sum(row[f"t_{k}_ms"] for k in ("descriptors", "matching", "rejection", "ransac"))
    assert 0 < stages <= row["t_total_ms"] <= row["t_cpu_ms"] * 1.02 + 0.2


def test_dataset_recommended_settings_and_overrides(data_dir):
    kitti = make_sweep("overlap", "kitti00", ExperimentOptions(trials=1, overlaps=[0.3]))
    cfg = kitti.tasks()[0].config
    assert cfg["ransac"]["threshold"] == 2.0  # the KITTI objects preset
    assert any(t.config["rejection_params"].get("tau") == 2.0 for t in kitti.tasks())
    mine = make_sweep(
        "overlap", "kitti00", ExperimentOptions(trials=1, overlaps=[0.3], threshold=4.0)
    )
    assert mine.tasks()[0].config["ransac"]["threshold"] == 4.0
    airsim = make_sweep("table", "airsim-guo", ExperimentOptions(trials=1))
    assert {t.config["ransac"]["threshold"] for t in airsim.tasks()} == {5.0}
