"""A run's scalar log packed into one file (evaaa_baselines.logs, scripts/pack_record.py): every row reads
back as it was, bench_train.py's figures do not change, a run resumed after packing adds its new rows after the
packed ones, and a record's runs are found and packed by the script."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import yaml
from helpers import load_script

from evaaa_baselines.logs import PACKED, SCALARS, has_scalar, pack, read_scalar, tags

TIMES = {1000: 1.0, 2000: 11.0, 3000: 21.0, 4000: 31.0, 5000: 41.0}


def write_run(run_dir: Path) -> dict[str, str]:
    files = {
        "time/env_steps_per_s": "".join(f"{s},{s / t}\n" for s, t in TIMES.items()),
        "train/updates": "".join(f"{s},{30 * i}\n" for i, s in enumerate(TIMES)),
        "episode/end/FoodOutOfRange": "4424,1.0\n7376,0.0\n",
        "episode/return": "4424,-852.7284545898438\n4760,-616.1174926757812\n",
    }
    for tag, text in files.items():
        path = run_dir / SCALARS / f"{tag}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    (run_dir / ".hydra").mkdir()
    (run_dir / ".hydra" / "config.yaml").write_text("algo: {name: ppo}\n")
    return files


def test_a_packed_log_reads_back_row_for_row_and_bench_train_sees_the_same(tmp_path):
    files = write_run(tmp_path)
    bench = load_script("bench_train")
    before = bench.read_throughput(tmp_path, "dreamer_xs", skip=0.25)
    rows = {tag: read_scalar(tmp_path, tag) for tag in files}
    assert pack(tmp_path) == len(files)
    assert not (tmp_path / SCALARS).exists() and (tmp_path / PACKED).is_file()
    assert tags(tmp_path) == sorted(files) and all(has_scalar(tmp_path, t) for t in files)
    for tag, text in files.items():  # the very text of every value
        assert read_scalar(tmp_path, tag) == rows[tag] == [tuple(line.split(",")) for line in text.splitlines()]
    after = bench.read_throughput(tmp_path, "dreamer_xs", skip=0.25)
    assert dataclasses.asdict(after) == dataclasses.asdict(before) and after.gradient_steps == 120
    assert pack(tmp_path) == 0  # nothing left to pack


def test_rows_written_after_packing_follow_the_packed_ones_and_pack_again(tmp_path):
    write_run(tmp_path)
    pack(tmp_path)
    (tmp_path / SCALARS / "episode").mkdir(parents=True)
    (tmp_path / SCALARS / "episode" / "return.csv").write_text("9000,-1.5\n")  # a resumed session's logger
    expected = [("4424", "-852.7284545898438"), ("4760", "-616.1174926757812"), ("9000", "-1.5")]
    assert read_scalar(tmp_path, "episode/return") == expected
    assert pack(tmp_path) == 1 and read_scalar(tmp_path, "episode/return") == expected
    assert (tmp_path / PACKED).read_text().startswith("tag,step,value\n")


def test_pack_record_packs_every_run_of_a_record(tmp_path, capsys):
    for name in ("ppo/direct-1-1/seed0", "dqn/curriculum/seed1"):
        write_run(tmp_path / "runs" / name)
    assert load_script("pack_record").main([f"root={tmp_path}"]) == 0
    out = capsys.readouterr().out
    assert "2 run directories" in out and "8 scalar files packed" in out
    assert not list(tmp_path.rglob("logs/scalars/*")) and len(list(tmp_path.rglob("logs/scalars.csv"))) == 2


HYDRA = """hydra:
  run:
    dir: docs/results/x/record/runs/ppo/direct-1-1/seed0
  runtime:
    version: 1.3.2
    cwd: /some/machine/repo
    config_sources:
    - path: /some/machine/repo/conf
      schema: file
    output_dir: /some/machine/repo/docs/results/x/record/runs/ppo/direct-1-1/seed0
"""


def test_pack_record_makes_the_hydra_files_name_paths_relative_to_where_the_run_ran(tmp_path):
    run = tmp_path / "runs" / "ppo" / "direct-1-1" / "seed0"
    write_run(run)
    (run / ".hydra" / "hydra.yaml").write_text(HYDRA)
    (run / ".hydra" / "hydra.session-1.yaml").write_text(HYDRA)
    assert load_script("pack_record").main([f"root={tmp_path}"]) == 0
    for name in ("hydra.yaml", "hydra.session-1.yaml"):
        text = (run / ".hydra" / name).read_text()
        assert "/some/machine" not in text
        runtime = yaml.safe_load(text)["hydra"]["runtime"]
        assert runtime["cwd"] == "." and runtime["config_sources"][0]["path"] == "conf"
        assert runtime["output_dir"] == "docs/results/x/record/runs/ppo/direct-1-1/seed0"
    assert (run / ".hydra" / "config.yaml").read_text() == "algo: {name: ppo}\n"  # the settings are left alone
