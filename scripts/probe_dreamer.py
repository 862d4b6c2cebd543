"""How well a DreamerV3 run's world model knows the EVs the reward is computed from.

    python scripts/probe_dreamer.py run=runs/1-1/dreamer_xs/all-drive_reduction/seed0

Decodes the interoception from the posterior of the run's last checkpoint on replayed sequences around the last
eating steps its memory-mapped replay holds, and prints the mean absolute error of each EV, in raw units, on the
eating steps and on the others; then how much of the EVs a linear read-out finds in the encoder's embedding, the
stochastic latent, the deterministic state and both, which tells where in the model the EVs are lost
(docs/training.md, "What was tried on level 1-1").
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from evaaa_baselines import cli
from evaaa_baselines.cli import option
from evaaa_baselines.dreamer import ev_decoding_errors


@dataclass
class ProbeConfig:
    run: str = option("", "a DreamerV3 run directory (its checkpoint.pt and replay/)",
                      check=(lambda v: bool(v), "a run directory"))
    sequences: int = option(64, "replayed sequences of 32 steps", check=(lambda v: v >= 1, ">= 1"))


def main(argv: list[str] | None = None) -> int:
    cfg = cli.parse(ProbeConfig, argv, prog="probe_dreamer.py", description=__doc__.split("\n\n")[0],
                    examples=["run=runs/1-1/dreamer_xs/all-drive_reduction/seed0 sequences=32"])
    result = ev_decoding_errors(cfg.run, cfg.sequences)
    print(f"{cfg.run}: {result['env_steps']:,} env steps; {result['sequences']} sequences, "
          f"{result['eating_steps']} eating steps")
    print("mean absolute error of the decoded EVs (raw units)")
    for name in ("eating", "other"):
        print(f"  {name + ' steps':<21}" + "  ".join(f"{ev} {err:.2f}" for ev, err in result[name].items()))
    if result["linear_probe"]:
        print("a linear read-out of the EVs (symlog) from each part of the model, fitted on half of the sequences: "
              "the share of their variance it explains on the other half (1: all of it; 0: no more than the mean)")
        for name, shares in result["linear_probe"].items():
            print(f"  {name:<21}" + "  ".join(f"{ev} {r2:5.2f}" for ev, r2 in shares.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
