"""scripts/bench_gpu.py runs end to end on a CPU at tiny sizes and writes every figure it promises (its speed is
measured on a GPU box; no figure is asserted here beyond being there and positive)."""

from __future__ import annotations

import json

from helpers import load_script


def test_the_gpu_bench_runs_on_a_cpu_at_tiny_sizes_and_writes_its_json(tmp_path):
    out = tmp_path / "gpu.json"
    bench = load_script("bench_gpu")
    code = bench.main(
        [
            "device=cpu",
            "tiny=true",
            "sizes=[XS]",
            "variants=[eager,graphs]",
            "updates=1",
            "algos=[ppo]",
            "worlds=[2]",
            "env_threads=[1]",
            f"out={out}",
        ]
    )
    assert code == 0
    figures = json.loads(out.read_text())
    assert figures["machine"]["device"] == "cpu" and figures["machine"]["cpu"]
    eager = figures["dreamer"]["XS"]["eager"]
    for key in ("ms_per_update", "updates_per_s", "aten_ops", "step_from_replay_ms", "step_from_replay_prefetch_ms"):
        assert eager[key] > 0, key
    assert eager["finite_losses"] is True and eager["peak_memory_gb"] > 0
    assert figures["dreamer"]["XS"]["graphs"] == {
        "size": "XS",
        "variant": "graphs",
        "skipped": "CUDA graphs need a CUDA device",
    }
    replay = figures["replay"]["XS"]
    assert replay["transitions"] == 256 and replay["draw_ms"] > 0 and replay["draw_slice_sampler_ms"] > 0
    (loop,) = figures["loops"]
    assert loop["algo"] == "ppo" and loop["num_envs"] == 2 and loop["env_threads"] == 1 and loop["env_steps"] == 128
    assert loop["steady_env_steps_per_s"] > 0 and "error" not in loop
