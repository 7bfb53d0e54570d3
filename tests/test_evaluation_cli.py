"""`sgloc experiment`: each experiment writes its results folder; bad input exits 2."""

from __future__ import annotations

import yaml

from sgloc.cli import main
from sgloc.evaluation.report import read_csv


def test_table_experiment_writes_csv_table_figure_and_config(tmp_path):
    out = tmp_path / "t"
    rc = main(["experiment", "table", "--trials", "2", "--out", str(out), "--workers", "1",
               "--descriptors", "histogram"])  # fmt: skip
    assert rc == 0
    rows = read_csv(out / "trials.csv")
    assert len(rows) == 4  # 2 trials x {none, neighbor}
    assert {r["rejection"] for r in rows} == {"none", "neighbor"}
    md = (out / "table.md").read_text()
    assert "Histogram + neighbor** (ours)" in md and "(paper)" in md
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg["experiment"]["trials"] == 2
    assert len(cfg["localizer_configs"]) == 2
    assert (out / "error_distribution.png").stat().st_size > 1000
    # tables and figures can be re-made from the CSV without running trials
    out2 = tmp_path / "again"
    rc = main(["experiment", "table", "--trials", "2", "--out", str(out2),
               "--descriptors", "histogram", "--from-csv", str(out / "trials.csv")])  # fmt: skip
    assert rc == 0 and (out2 / "table.md").read_text().split("\n")[4:] == md.split("\n")[4:]


def test_threshold_pr_overlap_and_matches(tmp_path):
    common = ["--trials", "1", "--workers", "1", "--descriptors", "fast"]
    assert main(["experiment", "threshold", "--thresholds", "3,5", "--out",
                 str(tmp_path / "th"), *common]) == 0  # fmt: skip
    assert (tmp_path / "th" / "error_vs_threshold.png").is_file()
    assert (tmp_path / "th" / "error_distribution_5m.png").is_file()
    assert main(["experiment", "pr", "--thresholds", "3,5", "--out", str(tmp_path / "pr"),
                 *common]) == 0  # fmt: skip
    assert (tmp_path / "pr" / "pr_curves.png").is_file()
    assert main(["experiment", "overlap", "--dataset", "object-world", "--overlaps", "0.3,0.7",
                 "--out", str(tmp_path / "ov"), *common]) == 0  # fmt: skip
    rows = read_csv(tmp_path / "ov" / "trials.csv")
    assert sorted({r["overlap"] for r in rows}) == [0.3, 0.7]
    assert (tmp_path / "ov" / "overlap_boxplots.png").is_file()
    assert main(["experiment", "matches", "--out", str(tmp_path / "m")]) == 0
    assert (tmp_path / "m" / "matches.png").stat().st_size > 1000


def test_bad_input_is_one_line_exit_2(tmp_path, capsys):
    assert main(["experiment", "nonsense", "--out", str(tmp_path / "x")]) == 2
    assert main(["experiment", "table", "--dataset", "nowhere", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "unknown dataset 'nowhere'" in err
    assert main(["experiment", "table", "--trials", "0"]) == 2
