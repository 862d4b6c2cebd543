"""reproduce.py's cells on Ray (a real local cluster on 127.0.0.1 with two workers) and through submitit's local
executor; a Ray worker killed mid-cell. Needs the `cluster` extra (scripts/setup.sh installs it). train.py -m through
the launcher presets: tests/test_launchers.py."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
from helpers import load_script, ray_head

from evaaa_baselines.paper.cell_status import status
from evaaa_baselines.paper.cells import Cell, Command, Layout
from evaaa_baselines.paper.protocol import load_protocol
from evaaa_baselines.paper.running import Runner

ray = pytest.importorskip("ray")
submitit = pytest.importorskip("submitit")
reproduce = load_script("reproduce")


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A Ray head on 127.0.0.1 with two worker CPUs; its address."""
    with ray_head(tmp_path_factory.mktemp("ray")) as address:
        yield address


def _cells(tmp_path: Path, train_code: str):
    """A training cell (``train_code``), an evaluation that needs its model, a report."""
    lay = Layout(tmp_path)
    run_dir = lay.runs / "a"
    model = run_dir / "model-0-1-1.pt"
    out = lay.evals / "a"
    train = Cell("train/ppo/a", "train", [Command(["-c", train_code])], 1.0, "a", run_dir=run_dir, final_model=model)
    ev = Cell(
        "eval/a",
        "eval",
        [
            Command(
                [
                    "-c",
                    f"import pathlib; assert pathlib.Path({str(model)!r}).exists(); "
                    f"o=pathlib.Path({str(out)!r}); o.mkdir(parents=True, exist_ok=True); "
                    "(o/'episodes.csv').write_text('x')",
                ],
                out,
            )
        ],
        1.0,
        "e",
        needs=[model],
        needs_cells=["train/ppo/a"],
    )
    rep_out = tmp_path / "report"
    rep = Cell(
        "report",
        "report",
        [
            Command(
                [
                    "-c",
                    f"import pathlib; o=pathlib.Path({str(rep_out)!r}); "
                    "o.mkdir(exist_ok=True); (o/'report.md').write_text('r')",
                ]
            )
        ],
        1.0,
        "r",
        needs_cells=["train/ppo/a", "eval/a"],
        report_out=rep_out,
    )
    return lay, [train, ev, rep]


def _runs(lay: Layout, name: str) -> int:
    return lay.log(name).read_text().count("\n== ")


def test_a_ray_worker_killed_mid_cell_is_resumed_and_no_done_cell_runs_twice(tmp_path, ray_cluster):
    # the training writes a checkpoint and the pid of the Ray worker that runs it, then waits; resumed
    # (resume=true, what command_now gives a started run), it writes its model
    pid_file = tmp_path / "worker.pid"
    run_dir = tmp_path / "runs" / "a"
    code = (
        f"import os,pathlib,sys,time; d=pathlib.Path({str(run_dir)!r}); d.mkdir(parents=True, exist_ok=True)\n"
        "if 'resume=true' in sys.argv: (d/'model-0-1-1.pt').write_text('m'); raise SystemExit(0)\n"
        f"(d/'checkpoint.pt').write_text('c'); pathlib.Path({str(pid_file)!r}).write_text(str(os.getppid()))\n"
        "time.sleep(120)"
    )
    lay, cells = _cells(tmp_path, code)
    child = []

    def kill_worker():
        deadline = time.monotonic() + 120
        while not pid_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        worker = int(pid_file.read_text())
        child.extend(subprocess.run(["pgrep", "-P", str(worker)], capture_output=True, text=True).stdout.split())
        os.kill(worker, signal.SIGKILL)  # the worker is lost mid-cell, its training with it

    killer = threading.Thread(target=kill_worker)
    killer.start()
    runner = Runner(
        load_protocol("smoke"),
        cells,
        lay,
        executor="ray",
        ray_address=ray_cluster,
        ray_retries=2,
        progress=False,
        echo=lambda s: None,
    )
    assert runner.run(cells) == 0
    killer.join()
    # Ray ran the lost cell again; it continued from the checkpoint the lost one left
    log = lay.log("train/ppo/a").read_text()
    assert _runs(lay, "train/ppo/a") == 2 and log.rstrip().endswith("resume=true")
    assert child and not Path(f"/proc/{child[0]}").exists()  # the lost worker's training died with it
    assert _runs(lay, "eval/a") == 1 and _runs(lay, "report") == 1
    assert all(status(c, lay, cells) == "done" for c in cells)
    # the same command again: every cell done, nothing runs, no file changes
    before = {p: p.stat().st_mtime for p in tmp_path.rglob("*") if p.is_file()}
    todo = [c for c in cells if status(c, lay, cells) != "done"]
    assert todo == []
    # a task handed a done cell (a retry whose first try finished) does nothing
    assert (
        Runner(
            load_protocol("smoke"),
            cells,
            lay,
            executor="ray",
            ray_address=ray_cluster,
            progress=False,
            echo=lambda s: None,
        ).run(cells)
        == 0
    )
    assert {p: p.stat().st_mtime for p in tmp_path.rglob("*") if p.is_file()} == before


def _done_code(run_dir: Path) -> str:
    return (
        f"import pathlib; d=pathlib.Path({str(run_dir)!r}); d.mkdir(parents=True, exist_ok=True); "
        "(d/'model-0-1-1.pt').write_text('m')"
    )


def test_cells_run_through_submitit_s_local_executor(tmp_path):
    lay, cells = _cells(tmp_path, _done_code(tmp_path / "runs" / "a"))
    runner = Runner(
        load_protocol("smoke"),
        cells,
        lay,
        executor="slurm",
        submitit_cluster="local",
        slurm={"timeout_min": 5},
        progress=False,
        echo=lambda s: None,
    )
    assert runner.run(cells) == 0
    assert all(status(c, lay, cells) == "done" for c in cells)
    assert all(_runs(lay, c.name) == 1 for c in cells)
    assert list((tmp_path / "submitit").rglob("*_submitted.pkl"))  # the jobs went through submitit


#: a protocol with one cell of each kind the smoke protocol has (a reference, a training, the choice of the compared
#: mode from the training's validation rows, the evaluation of its model in both modes, the report) and one more
#: reference that is not selected: the whole smoke protocol runs on the local engine in test_protocol.py; here the
#: engines carry every kind of cell, the smallest of each (one 128-step training, one testbed episode per command)
ENGINE = """
name: engine
stage_steps: 128
seeds: [0]
levels: [1-1]
training:
  overrides: [preset=debug, logger=csv, progress=false, eval.every=128, eval.episodes=2, eval.both_modes=true]
  curriculum: false
algorithms:
  ppo: {steps_per_second: 30, overrides: [reward=original]}
evaluation:
  modes: [sample, mode]
  compare: validation
  testbeds: {levels: [two-resource-temp], episodes: 1, num_envs: 1}
  steps_per_second: 300
references: {policies: [oracle, random], levels: [two-resource-temp], episodes: 1, num_envs: 1, steps_per_second: 300}
report: {out: null}
"""
ENGINE_CELLS = ["ref/oracle", "train/ppo/direct-1-1/seed0", "choose/acting", "eval/ppo/direct-1-1/seed0", "report"]


@pytest.mark.slow
@pytest.mark.parametrize("executor", ["ray", "slurm"])
def test_every_kind_of_protocol_cell_end_to_end_on_an_engine(tmp_path, executor, request):
    spec = tmp_path / "engine.yaml"
    spec.write_text(ENGINE)
    args = [f"protocol={spec}", f"root={tmp_path / 'root'}", "progress=false", f"executor={executor}"]
    args.append(f"cells=[{','.join(ENGINE_CELLS)}]")
    if executor == "ray":
        args.append(f"ray_address={request.getfixturevalue('ray_cluster')}")
    else:
        args.append("submitit_cluster=local")
    assert reproduce.main(args) == 0
    root = tmp_path / "root"
    from evaaa_baselines.paper.cells import build_cells

    cells = build_cells(load_protocol(spec), root)
    chosen = [c for c in cells if c.name in ENGINE_CELLS]
    assert sorted(c.name for c in chosen) == sorted(ENGINE_CELLS)
    assert sorted({c.kind for c in chosen}) == ["choose", "eval", "ref", "report", "train"]
    lay = Layout(root)
    assert all(status(c, lay, cells) == "done" for c in chosen if c.kind != "report")
    assert status(next(c for c in cells if c.kind == "report"), lay, cells) == "partial"  # made on what there is
    assert [c.name for c in cells if c not in chosen] == ["ref/random"]
    assert all(status(c, lay, cells) == "todo" for c in cells if c not in chosen)  # the others not touched
    # every command of every chosen cell ran once (an evaluation cell has one command per acting mode)
    assert all(_runs(lay, c.name) == len(c.commands) for c in chosen)
    assert any(len(c.commands) > 1 for c in chosen)
    assert "Fig. 4a, left" in (root / "report" / "report.md").read_text()


def test_a_cell_at_its_slurm_time_limit_checkpoints_and_its_job_is_requeued_to_continue(tmp_path):
    """submitit's timeout signal (SIGUSR2, here from its local executor's controller, signal_delay_s before the time
    limit; SLURM sends it the same way) to a job mid-training: the training is stopped as a Ctrl-C stops it and writes
    its checkpoint, submitit requeues the job, and the requeued job continues the cell (resume=true) to done."""
    run_dir = tmp_path / "runs" / "a"
    code = (
        f"import pathlib,signal,sys,time; d=pathlib.Path({str(run_dir)!r}); d.mkdir(parents=True, exist_ok=True)\n"
        "if 'resume=true' in sys.argv:\n"
        "    assert (d/'checkpoint.pt').read_text() == 'c'; (d/'model-0-1-1.pt').write_text('m'); raise SystemExit(0)\n"
        "def stop(*a): (d/'checkpoint.pt').write_text('c'); raise SystemExit(130)\n"
        "signal.signal(signal.SIGINT, stop); (d/'started').write_text('')\n"
        "time.sleep(300)"
    )
    lay, cells = _cells(tmp_path, code)
    runner = Runner(
        load_protocol("smoke"),
        cells[:1],
        lay,
        executor="slurm",
        submitit_cluster="local",
        # a one-minute job: the local executor sends its timeout signal 30 s before the end
        slurm={"timeout_min": 1},
        progress=False,
        echo=lambda s: None,
    )
    assert runner.run(cells[:1]) == 0
    assert status(cells[0], lay, cells) == "done"
    log = lay.log("train/ppo/a").read_text()
    # stopped by one SIGINT (its checkpoint written), then the requeued job ran it again with resume=true
    assert _runs(lay, "train/ppo/a") == 2 and log.rstrip().endswith("resume=true"), log
    errors = "".join(p.read_text() for p in (tmp_path / "submitit").rglob("*_log.*"))
    assert "Requeued job" in errors, errors[-3000:]
