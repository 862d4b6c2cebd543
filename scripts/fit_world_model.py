"""How fast a fresh DreamerV3 world model learns what eating does, from a run's stored replay alone.

    python scripts/fit_world_model.py run=runs/1-1/dreamer_xs/all-squared/seed0 updates=2000 "set=[consume_share=0.5]"

Trains a new world model (the run's config, with `set` overriding `algo` keys) on the first 90 % of the run's
memory-mapped replay and, every `every` gradient steps, imagines one step of each action from the posterior before
each held-out eating step: the decoded satiation + hydration change of eating against the other four actions
(`eat effect`; beside it the real change, and the change the posterior decodes once it has seen the observation
after eating), the same on up to 64 eating steps it trains on (`on trained`: learnt there but not on the held-out
ones means too few meals to generalise from) and where eating found nothing (should stay near 0).  First it prints
how well each observation key tells a successful eat press from a fruitless one (a logistic read-out's AUC):
whether the data hold what the model should learn; last, the same read-out from the trained latent: whether the
model keeps it.  No env, actor or critic: world-model settings compared in minutes on the same data
(docs/lab-notes.md, "What was tried on level 1-1").
"""

from __future__ import annotations

import csv
import sys
from dataclasses import dataclass
from pathlib import Path

from evaaa.sensors import SENSORS, resolve_modalities
from evaaa_baselines import cli
from evaaa_baselines.cli import option


@dataclass
class FitConfig:
    run: str = option(
        "", "a DreamerV3 run directory (its checkpoint.pt and replay/)", check=(lambda v: bool(v), "a run directory")
    )
    updates: int = option(2000, "gradient steps", check=(lambda v: v >= 1, ">= 1"))
    every: int = option(250, "gradient steps between measurements", check=(lambda v: v >= 1, ">= 1"))
    set: list[str] = option([], "algo keys to override, e.g. [consume_share=0.5,model.stochastic=32]")
    keys: list[str] | None = option(
        None,
        "observation keys the new model sees (null: the run's), e.g. [interoception,olfaction] to leave the pixels out",
        choices=lambda: resolve_modalities(list(SENSORS)),
    )
    held_out: float = option(
        0.1, "share of the replay's rows kept for measuring", check=(lambda v: 0 < v < 1, "in (0, 1)")
    )
    seed: int = option(0, "seed of the new model and of the batches", check=cli.SEED)
    out: str = option("", "a CSV file for the measurements (empty: print only)")
    threads: int | None = option(
        None,
        "torch intra-op threads (null: torch's default), as train.py's threads=",
        check=(lambda v: v is None or v >= 1, "null or >= 1"),
    )
    device: str = option(
        "cpu", "where the new model trains: cpu, cuda, cuda:N or auto (CUDA when available), as train.py's device="
    )


def main(argv: list[str] | None = None) -> int:
    cfg = cli.parse(
        FitConfig,
        argv,
        prog="fit_world_model.py",
        description=__doc__.split("\n\n")[0],
        examples=['run=runs/1-1/dreamer_xs/all-squared/seed0 updates=1000 "set=[consume_share=0.5]"'],
    )
    # torch and DreamerV3's code load once --help and the command line have passed
    import torch

    from evaaa_baselines.devices import DeviceError, resolve_device
    from evaaa_baselines.dreamer.probes import eat_success_readout, fit_world_model

    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    try:
        device = resolve_device(cfg.device)
    except DeviceError as error:
        cli.fail("fit_world_model.py", str(error))
    print(
        f"{cfg.run}: a new world model on {device}, {cfg.updates:,} gradient steps"
        + (f", {' '.join(cfg.set)}" if cfg.set else "")
        + (f", seeing {', '.join(cfg.keys)}" if cfg.keys else "")
    )
    readout = eat_success_readout(cfg.run, cfg.held_out)
    print(
        f"its replay: {readout['presses']:,} eat presses, {readout['ate']} of them ate or drank "
        f"({readout['held_out_ate']} in the held-out rows); how well a logistic read-out of the observation pressed "
        "on tells which (held-out AUC, 0.5: chance): " + ", ".join(f"{k} {v:.3f}" for k, v in readout["auc"].items())
    )
    print(
        f"{'updates':>8} {'seconds':>8} {'eat effect':>11} {'on trained':>11} {'real':>7} {'posterior':>10} "
        f"{'eat, nothing there':>19}"
    )

    def report(row: dict) -> None:
        print(
            f"{row['updates']:>8,} {row['seconds']:>8.0f} {row['eat_effect']:>11.3f} "
            f"{row['eat_effect_trained']:>11.3f} {row['real_effect']:>7.3f} "
            f"{row['posterior_effect']:>10.3f} {row['eat_effect_nothing']:>19.3f}",
            flush=True,
        )

    rows = fit_world_model(cfg.run, cfg.updates, cfg.every, cfg.set, cfg.held_out, cfg.seed, report, cfg.keys, device)
    last = rows[-1]
    print(
        f"held-out eating steps: {last['held_out_eating_steps']}; the same read-out of the trained latent on the "
        f"observation pressed on (held-out AUC): encoder's embedding {last['latent_auc_embedding']:.3f}, "
        f"stochastic state {last['latent_auc_state']:.3f}, deterministic state {last['latent_auc_belief']:.3f}, "
        f"deterministic state after the eat action {last['latent_auc_belief_after_eat']:.3f}"
    )
    if cfg.out:
        Path(cfg.out).parent.mkdir(parents=True, exist_ok=True)
        with open(cfg.out, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[-1]))  # the last row adds the latent's read-out
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
