"""The acting mode a protocol's claims compare, chosen from its validation rows before any test evaluation
(``evaluation.compare: validation``; docs/reports.md, "The paper's protocol at CPU scale").

Every training run of such a protocol records its in-training validation evaluations in both acting modes
(``eval.both_modes=true``: the same episodes of the same validation worlds played by sampling and by the most
likely action, rows of ``eval.csv`` with their own ``acting``).  The networks the test evaluations will evaluate are
each stage's final one, so each counts by its stage's last validation evaluation; the mode chosen is the one whose
episodes there, pooled over every network of every run, survive longer on average (the first of the protocol's
modes where they tie).  A network with one mode only (an algorithm without an action distribution, DQN, which acts
the same either way) is left out and named.  The choice is written once (``compared_mode.json``, with the numbers it
rests on) by the protocol's cell ``choose/acting``, which runs after every training and before every checkpoint's
test evaluation and refuses to run where one exists; the report reads it and states it.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

MODES = ("sample", "mode")
RULE = (
    "the acting mode whose in-training validation evaluations survive longer (mean decisions survived), pooled over "
    "every network's last validation evaluation (each stage's final network, the one the test evaluations evaluate), "
    "the same episodes played in both modes; the first of the protocol's modes on a tie; networks evaluated in one "
    "mode only (no action distribution) left out"
)


class ChoiceError(ValueError):
    """Inputs the choice cannot be made from; the message names the key and what it needs."""


def _mode(acting: str) -> str:
    return str(acting).split("+")[0]  # `sample+epsilon=0.05` is sampled


def validation_networks(run_dirs: Sequence[str | Path]) -> tuple[list[dict], list[str]]:
    """Each network's last validation evaluation in both modes (run, stage, level, env_steps, and per mode the
    decisions each episode survived), and a line per network or run left out."""
    networks: list[dict] = []
    left_out: list[str] = []
    for run in map(Path, run_dirs):
        path = run / "eval.csv"
        if not path.is_file():
            left_out.append(f"{run}: no eval.csv")
            continue
        rows = pd.read_csv(path)
        missing = {"env_steps", "stage", "level", "worlds", "acting", "steps"} - set(rows.columns)
        if missing:
            left_out.append(f"{run}: eval.csv without {', '.join(sorted(missing))} (per-episode rows)")
            continue
        rows = rows[rows["worlds"].astype(str) == "validation"]
        for stage, of_stage in rows.groupby("stage", sort=True):
            last = of_stage[of_stage["env_steps"] == of_stage["env_steps"].max()]
            by_mode = {m: last[last["acting"].map(_mode) == m]["steps"].astype(float).tolist() for m in MODES}
            level = str(last["level"].iloc[0])
            if not all(by_mode.values()):
                have = ", ".join(m for m in MODES if by_mode[m]) or "none"
                left_out.append(f"{run} stage {stage} ({level}): one acting mode only ({have})")
                continue
            networks.append(
                {"run": str(run), "stage": int(stage), "level": level, "env_steps": int(last["env_steps"].iloc[0])}
                | by_mode
            )
    return networks, left_out


def summary(steps: Sequence[float]) -> dict:
    """Episodes, mean and interquartile mean of decisions survived."""
    x = np.asarray(steps, dtype=float)
    return {
        "episodes": int(x.size),
        "mean": round(float(x.mean()), 2),
        "iqm": round(float(stats.trim_mean(x, 0.25)), 2),
    }


def choose(run_dirs: Sequence[str | Path], first: str = "sample", epsilon: float = 0.0) -> dict:
    """The choice from the runs' validation rows (:data:`RULE`), with the numbers it rests on: ``chosen``
    (``sample`` or ``mode``), ``compare`` (the ``acting`` the test evaluations record for it, with ``+epsilon``),
    ``survival`` per mode (pooled episodes, mean, IQM), the networks and runs counted, and those left out."""
    if first not in MODES:
        raise ChoiceError(f"first: {first!r} is not an acting mode; allowed: {', '.join(MODES)}")
    networks, left_out = validation_networks(run_dirs)
    if not networks:
        raise ChoiceError(
            "runs: no network has a validation evaluation in both acting modes (train with eval.both_modes=true); "
            + ("; ".join(left_out) if left_out else "no run given")
        )
    pooled = {m: summary([s for n in networks for s in n[m]]) for m in MODES}
    other = next(m for m in MODES if m != first)
    chosen = other if pooled[other]["mean"] > pooled[first]["mean"] else first
    return {
        "chosen": chosen,
        "compare": chosen + (f"+epsilon={epsilon:g}" if epsilon else ""),
        "rule": RULE,
        "survival": pooled,
        "networks": len(networks),
        "runs": len({n["run"] for n in networks}),
        "left_out": left_out,
        "per_network": [
            {k: n[k] for k in ("run", "stage", "level", "env_steps")} | {m: summary(n[m])["mean"] for m in MODES}
            for n in networks
        ],
        "chosen_at": datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ"),
    }


def checkpoint_evaluations(evals: str | Path) -> list[Path]:
    """The ``episodes.csv`` files under ``evals`` that hold a checkpoint's evaluation (a policy that is a ``.pt``
    file; the reference agents' are not), set-aside folders included: evidence of a test evaluation made already."""
    found = []
    for path in sorted(Path(evals).rglob("episodes.csv")):
        with open(path, newline="") as f:
            row = next(csv.DictReader(f), None)
        if row is not None and str(row.get("policy", "")).endswith(".pt"):
            found.append(path)
    return found


def write_choice(out: str | Path, choice: dict) -> Path:
    """Write ``choice`` to ``out``, which must not exist (the choice is made once): whole or not at all."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(choice, indent=1) + "\n")
    try:
        os.link(tmp, out)  # fails where out exists: never a second choice over the first
    except FileExistsError:
        raise ChoiceError(f"out: {out} exists: the compared mode is chosen once; nothing was written") from None
    finally:
        tmp.unlink(missing_ok=True)
    return out


def read_choice(path: str | Path) -> dict:
    """A choice written by :func:`write_choice`; :class:`ChoiceError` naming ``compare_from`` where it cannot be read."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as err:
        raise ChoiceError(
            f"compare_from: cannot read {path} ({err.__class__.__name__}); the protocol's cell choose/acting writes it"
        ) from None
    if not isinstance(data, dict) or data.get("chosen") not in MODES or not isinstance(data.get("survival"), dict):
        raise ChoiceError(f"compare_from: {path} is not a choice of choose_acting.py (chosen: sample or mode)")
    return data


def choice_text(data: dict, name: str = "compared_mode.json") -> str:
    """The choice in one sentence with its numbers (the report's words)."""
    chosen = data["chosen"]
    other = next(m for m in MODES if m != chosen)
    s = data["survival"]

    def said(m: str) -> str:
        return f"mean {s[m]['mean']:,.1f} decisions (IQM {s[m]['iqm']:,.1f}, {s[m]['episodes']} episodes)"

    left = f"; {len(data.get('left_out', []))} left out (one acting mode only)" if data.get("left_out") else ""
    # a tie is decided by the protocol's order of modes, not by survival: said so
    tie = s[chosen]["mean"] == s[other]["mean"]
    why = (
        "the protocol's first mode, both surviving as long"
        if tie
        else "whose in-training validation evaluations survived longer"
    )
    return (
        f"chosen from validation rows before any test evaluation ({name}, {data.get('chosen_at', 'time unknown')}): "
        f"`{chosen}`, {why} — {said(chosen)} against "
        f"{said(other)} acting `{other}`, the same episodes, at the last validation evaluation of "
        f"{data['networks']} networks of {data['runs']} runs{left}"
    )
