"""How well a DreamerV3 run's world model knows the EVs, and what it says each action is worth.

    python scripts/probe_dreamer.py run=runs/1-1/dreamer_xs/all-drive_reduction/seed0

Decodes the interoception from the posterior of the run's last checkpoint on replayed sequences around the last
eating steps its memory-mapped replay holds, and prints the mean absolute error of each EV, in raw units, on the
eating steps and on the others; then how much of the EVs a linear read-out finds in the encoder's embedding, the
stochastic latent, the deterministic state and both, which tells where in the model the EVs are lost
(docs/lab-notes.md, "What was tried on level 1-1"). Then, from the same replayed states, one imagined step of every
action followed by the critic: each action's value against the mean of the five, the actor's probabilities and the
decoded change of satiation and hydration, for every state, the steps that really ate or drank, the eat actions that
found nothing, and the five steps before an eating step: whether imagination knows that eating pays where food is.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from evaaa_baselines import cli
from evaaa_baselines.cli import option


@dataclass
class ProbeConfig:
    run: str = option(
        "", "a DreamerV3 run directory (its checkpoint.pt and replay/)", check=(lambda v: bool(v), "a run directory")
    )
    model: str | None = option(
        None,
        "probe these networks instead of the checkpoint's (a model file of the same "
        "run, e.g. its model-best-0-1-1.pt: the peak against the end), on the run's "
        "replay",
    )
    sequences: int = option(64, "replayed sequences of 32 steps", check=(lambda v: v >= 1, ">= 1"))
    samples: int = option(8, "draws of the next latent for each imagined action", check=(lambda v: v >= 1, ">= 1"))


def main(argv: list[str] | None = None) -> int:
    cfg = cli.parse(
        ProbeConfig,
        argv,
        prog="probe_dreamer.py",
        description=__doc__.split("\n\n")[0],
        examples=[
            "run=runs/1-1/dreamer_xs/all-drive_reduction/seed0 sequences=32",
            "run=runs/1-1/dreamer_xs/all-sparse/seed0 model=runs/1-1/dreamer_xs/all-sparse/seed0/model-best-0-1-1.pt",
        ],
    )
    # DreamerV3's code (torch, TorchRL) loads once --help and the command line have passed
    from evaaa_baselines.dreamer.probes import ev_decoding_errors, imagined_action_values

    try:
        result = ev_decoding_errors(cfg.run, cfg.sequences, cfg.model)
    except (ValueError, FileNotFoundError) as err:
        cli.fail("probe_dreamer.py", str(err))
    print(
        f"{cfg.model or cfg.run}: {result['env_steps']:,} env steps; {result['sequences']} sequences, "
        f"{result['eating_steps']} eating steps"
    )
    print("mean absolute error of the decoded EVs (raw units)")
    for name in ("eating", "other"):
        print(f"  {name + ' steps':<21}" + "  ".join(f"{ev} {err:.2f}" for ev, err in result[name].items()))
    if result["linear_probe"]:
        print(
            "a linear read-out of the EVs (symlog) from each part of the model, fitted on half of the sequences: "
            "the share of their variance it explains on the other half (1: all of it; 0: no more than the mean)"
        )
        for name, shares in result["linear_probe"].items():
            print(f"  {name:<21}" + "  ".join(f"{ev} {r2:5.2f}" for ev, r2 in shares.items()))
    values = imagined_action_values(cfg.run, cfg.sequences, cfg.samples, cfg.model)
    whose = " (the run's last checkpoint's)" if cfg.model else ""
    print(
        f"one imagined step of each action, then the critic (r + gamma * c * v); the actor divides its advantages "
        f"by a return scale of {values['return_scale']:.3g}{whose}"
    )
    for name, group in values["groups"].items():
        print(f"  {name}: {group['states']:,} states")
        if not group["states"]:
            continue
        print(f"    {'':<30}" + "".join(f"{a:>9}" for a in group["policy"]))
        rows = {
            "actor's probability": group["policy"],
            "value above the mean": group["value_over_mean"],
            "best of the five (share)": group["best_share"],
        }
        for ev in ("satiation", "hydration"):
            rows[f"{ev} change, imagined"] = {a: change[ev] for a, change in group["ev_change"].items()}
        for label, row in rows.items():
            print(f"    {label:<30}" + "".join(f"{v:9.3f}" for v in row.values()))
        real = group["real_ev_change"]
        print(
            f"    {'real change, action taken':<30}satiation {real['satiation']:.3f}, hydration {real['hydration']:.3f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
