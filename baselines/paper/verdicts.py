"""The paper's claims on a report's inputs: :class:`ClaimInputs` (the inputs with the verdict rules and the
acting mode's choice) and its :func:`read_inputs`, :func:`claim_verdicts` (claims (a)–(e) judged by
:mod:`.claims` on the report's numbers) and the claims section (:func:`claims`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path

import pandas as pd

import evaaa

from ..reports.aggregate import STAT_COLUMNS, across_seeds, per_run, reference_stats
from ..reports.document import Document, Inputs, check_options, one_mode, source_words
from ..reports.document import read_inputs as read_report_inputs
from ..reports.equal_compute import matched_level, matched_reaching, matched_survival
from ..reports.load import MODEL_FILE, ReportError, RunRecord
from ..reports.matched import threshold
from ..reports.stats import MIN_SEEDS
from ..reports.survival import direct_views
from ..reports.testbeds import mean_testbed_success
from . import claims as rules


@dataclass
class ClaimInputs(Inputs):
    """A report's inputs (:class:`..reports.document.Inputs`) with what the claims are judged by: the verdict
    rules and, where the compared acting mode was chosen from validation rows, that choice."""

    # the verdict rules' settings (margins; a protocol's ``report.verdicts``); "fails" uses ``learned_factor`` where set
    verdict_rules: rules.Rules = field(default_factory=lambda: rules.Rules())
    # where ``compare`` was chosen from validation rows (a protocol's compared_mode.json, report option
    # ``compare_from``): that file's data, which the report states with its numbers; None: a fixed choice
    choice: dict | None = None

    @cached_property
    def verdicts(self) -> list[rules.Verdict]:
        """Claims (a)–(e) judged on these inputs (:func:`claim_verdicts`): the summary at the top and the claims
        section at the end share them."""
        return claim_verdicts(self)


def read_inputs(
    run_paths: Sequence[str | Path],
    eval_paths: Sequence[str | Path],
    *,
    survival: str = "eval",
    window: int = 20,
    bins: int = 20,
    acting: str | None = None,
    compare: str | None = None,
    learned: float | None = None,
    margin: float = 0.1,
    gain_margin: float = 0.1,
    choice: dict | None = None,
) -> ClaimInputs:
    """:func:`..reports.document.read_inputs` with the verdict rules' margins checked (after the report's own
    options, before anything is read) and the rules and ``choice`` attached."""
    check_options(survival, window, bins, learned)
    if not 0 <= margin < 1:
        raise ReportError(f"margin must lie in [0, 1), not {margin!r}")
    if not 0 < gain_margin < 1:
        raise ReportError(f"gain_margin must lie in (0, 1), not {gain_margin!r}")
    inp = read_report_inputs(
        run_paths,
        eval_paths,
        survival=survival,
        window=window,
        bins=bins,
        acting=acting,
        compare=compare,
        learned=learned,
    )
    verdict_rules = rules.Rules(
        margin=margin,
        fails_factor=learned if learned is not None else rules.Rules().fails_factor,
        gain_margin=gain_margin,
    )
    return ClaimInputs(
        **{f.name: getattr(inp, f.name) for f in fields(Inputs)}, verdict_rules=verdict_rules, choice=choice
    )


def _pooled_success(episodes: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """Per ``by`` (``run`` among them): the successes of all its testbed episodes pooled, as one seed's scores."""
    grouped = episodes.assign(_v=episodes["success"].astype(float)).groupby(list(by), sort=False)["_v"]
    return grouped.agg(success="mean", scores=lambda v: tuple(v.dropna())).reset_index()


def _survival_rows(inp: ClaimInputs, final: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame, set[str]]:
    """Claims (a)–(c)'s survival per level (``final``: the compared acting mode's final survival): each algorithm's
    curriculum runs where it has them, else its direct runs; the cells (b) compares; the algorithms with a
    curriculum."""
    runs = inp.by_dir
    empty = pd.DataFrame(columns=["algo", "setup", "level", *STAT_COLUMNS])
    # runs with every sense of every agent (the gate decides nothing: it explains undecided parts), less the
    # compute-matched ones (their budget is CPU minutes: they answer (c) alone)
    full = (
        final[final["run"].map(lambda d: runs[d].modality == "all" and runs[d].cpu_budget is None)]
        if len(final)
        else final
    )
    if len(full):
        full = direct_views(
            inp,
            full.assign(
                algo=full["run"].map(lambda d: runs[d].algo),
                setup=full["run"].map(lambda d: "curriculum" if runs[d].curriculum else "direct"),
            ),
            "algo",
        )
        # (b) at matched total env steps where direct runs of a curriculum stage's total exist, else at equal env
        # steps per stage (Fig. 4a right's two views)
        matched = full["view"].isin({"matched", "both"})
        has_match = set(zip(full.loc[matched, "algo"], full.loc[matched, "level"]))
        pair = pd.Series(list(zip(full["algo"], full["level"])), index=full.index)
        keep = (
            (full["view"] == "curriculum")
            | matched
            | ((full["view"] == "equal") & ~pair.isin(has_match))
            | full["stage_own"].isna()  # no curriculum of that algorithm on that level: nothing to pair it with
        )
        by_setup = across_seeds(full, ["algo", "setup", "level"], "survival")
        cmp = across_seeds(full[keep], ["algo", "setup", "level"], "survival")
    else:
        by_setup = cmp = empty
    with_cur = set(by_setup.loc[by_setup["setup"] == "curriculum", "algo"])
    survival = by_setup[(by_setup["setup"] == "curriculum") | ~by_setup["algo"].isin(with_cur)]
    return survival, cmp, with_cur


def _success_rows(inp: ClaimInputs, with_cur: set[str]) -> pd.DataFrame:
    """Claim (d)'s testbed success per agent (algorithm · training) and testbed: each run's furthest-trained
    checkpoint with every sense, curriculum runs where the algorithm (``with_cur``) has them."""

    def agent(d: Path) -> str:
        r = inp.runs[d]
        return f"{r.algo} · {r.training}"

    best = one_mode(inp.best, inp)
    best = (
        best[best["run"].map(lambda d: inp.runs[d].modality == "all" and inp.runs[d].cpu_budget is None)]
        if len(best)
        else best
    )
    if len(best):
        best = best[best["run"].map(lambda d: inp.runs[d].curriculum or inp.runs[d].algo not in with_cur)]
    success = (
        across_seeds(
            per_run(best, "success").assign(agent=lambda d: d["run"].map(agent)),
            ["agent", "level"],
            "success",
            success=True,
        )
        if len(best)
        else pd.DataFrame(columns=["agent", "level", *STAT_COLUMNS])
    )
    return success


def _generalisation_rows(inp: ClaimInputs) -> pd.DataFrame:
    """Claim (d)'s generalisation: mean testbed success of curriculum runs' stage models with every sense, per
    algorithm and level trained up to, with each cell's seeds (``units``)."""
    tests = one_mode(inp.testbed_episodes, inp)
    tests = (
        tests[
            tests["run"].map(lambda d: inp.runs[d].curriculum and inp.runs[d].modality == "all")
            & tests["policy"].map(lambda p: bool(MODEL_FILE.match(Path(p).name)))
        ]
        if len(tests)
        else tests
    )
    per_stage = (
        mean_testbed_success(tests).assign(agent=lambda d: d["run"].map(lambda x: inp.runs[x].algo))
        if len(tests)
        else None
    )
    gen = (
        across_seeds(per_stage, ["agent", "ckpt_level"], "success", success=True).rename(
            columns={"ckpt_level": "level"}
        )
        if per_stage is not None
        else pd.DataFrame(columns=["agent", "level", *STAT_COLUMNS])
    )
    if per_stage is not None:  # each cell's seeds by run, in its samples' order: (d) redraws a curriculum's together
        gen["units"] = list(
            per_stage.groupby(["agent", "ckpt_level"], sort=False)["run"].agg(lambda r: tuple(map(str, r)))
        )
    return gen


def _ablation_verdicts(inp: ClaimInputs, final: pd.DataFrame, bars: dict, vr: rules.Rules) -> list[rules.Verdict]:
    """Claim (e) per group of runs of one algorithm and training set-up with several modality sets (a missing
    verdict where there is none); ``bars``: the learning threshold per level."""
    out: list[rules.Verdict] = []
    # ablations: runs of one algorithm and training set-up (a level, or the curriculum) with several modality sets
    groups: dict[tuple, list[RunRecord]] = {}
    for r in inp.usable:  # one budget per group: a compute-matched run is no ablation's all-senses run
        groups.setdefault((r.algo, r.training, r.budget), []).append(r)
    groups = {k: v for k, v in groups.items() if len({r.modality for r in v}) > 1}
    if not groups:
        out.append(
            rules.missing(
                rules.ablations(pd.DataFrame(), pd.DataFrame()).claim,
                "no runs of one algorithm and level with several modality sets",
            )
        )
    for (algo, level, _), members in groups.items():
        dirs = {r.dir: r.modality for r in members}
        last = final[final["run"].isin(list(dirs)) & final["last"]] if len(final) else final
        surv = (
            across_seeds(last.assign(modality=last["run"].map(dirs)), ["modality"], "survival")
            if len(last)
            else pd.DataFrame(columns=["modality", *STAT_COLUMNS])
        )
        ab_best = one_mode(inp.best, inp)
        ab_best = ab_best[ab_best["run"].isin(list(dirs))] if len(ab_best) else ab_best
        succ = (
            across_seeds(
                _pooled_success(ab_best, ["run"]).assign(modality=lambda d, dirs=dirs: d["run"].map(dirs)),
                ["modality"],
                "success",
                success=True,
            )
            if len(ab_best)
            else pd.DataFrame(columns=["modality", *STAT_COLUMNS])
        )
        # the bar of the level the final networks were evaluated on (a curriculum's last stage)
        on = str(last["level"].iloc[0]) if len(last) and last["level"].nunique() == 1 else level
        v = rules.ablations(surv, succ, bars.get(on, float("nan")), vr)
        v.claim += f" ({algo}, trained on {level})"
        out.append(v)
    return out


def claim_verdicts(inp: ClaimInputs) -> list[rules.Verdict]:
    """The verdicts of claims (a)–(e) (:mod:`.claims`) from the report's inputs: survival per level from the final
    survival of every finished stage of runs with every sense (curriculum runs where an algorithm has them, else its
    direct runs), testbed success of each run's furthest-trained checkpoint, generalisation of curriculum runs'
    stage models, and the ablations: runs of one algorithm and training set-up with several modality sets."""
    order = list(evaaa.LEVELS)
    final = one_mode(inp.final, inp)
    survival, cmp, with_cur = _survival_rows(inp, final)

    success = _success_rows(inp, with_cur)
    refs = inp.evals.references
    ref_tests = (
        reference_stats(refs[refs["level"].isin(evaaa.TESTBEDS)], "success").rename(columns={"label": "agent"})
        if len(refs)
        else pd.DataFrame(columns=["agent", "level", *STAT_COLUMNS])
    )

    gen = _generalisation_rows(inp)
    vr = inp.verdict_rules
    factor = inp.learned_factor if inp.learned_factor is not None else vr.fails_factor
    refs_train = inp.reference_training
    bars = {
        lv: bar[0]
        for lv in order
        if (bar := threshold(refs_train, lv, factor) if len(refs_train) else None) is not None
    }
    where = matched_level(inp)
    if where is not None:  # (c) where the paper states it for one level, at equal compute
        msurv = matched_survival(inp)
        gate = inp.gate_of(True) if inp.learned_factor is not None else pd.DataFrame(columns=["algo", "learned"])
        ordering = rules.matched_ordering(
            msurv, bars.get(where[0], float("nan")), gate, matched_reaching(inp), *where, rules=vr
        )
    else:
        ordering = rules.algorithm_ordering(survival, bars, order, vr)
    verdicts = [
        rules.survival_falls(survival, order, rules=vr),
        rules.curriculum_beats_direct(cmp, order, rules=vr),
        ordering,
        rules.testbeds_below_ceiling(success, ref_tests, gen, order, vr),
    ]
    verdicts += _ablation_verdicts(inp, final, bars, vr)
    return verdicts


def claims(doc: Document, inp: ClaimInputs) -> None:
    """The paper's claims (a)–(e), one by one: reproduced, contradicted or not resolvable at this scale, with the
    rule and the numbers (:mod:`.claims`)."""
    acting = list(dict.fromkeys(inp.evals.checkpoints["acting"].astype(str))) if len(inp.evals.checkpoints) else []
    how = (
        f", acting {inp.compared}"
        if inp.compared
        else (f", acting {', '.join(f'`{a}`' for a in acting)}" if acting else "")
    )
    doc.md += [
        "## The paper's claims",
        "",
        "Each claim of the EVAAA paper judged against the numbers above by fixed rules that decide both ways "
        '(docs/reports.md, "The verdict rules"; margins from the protocol: '
        f"`margin={inp.verdict_rules.margin:g}`, `gain_margin={inp.verdict_rules.gain_margin:g}`). "
        f"**A beats B** (survival; testbed success the same on rates): the ratio of their IQMs with its 95 % bootstrap interval — above "
        f"{1 + inp.verdict_rules.margin:g} reproduces, at or under {1 + inp.verdict_rules.margin:g} contradicts (equal "
        "within the margin, or worse), straddling it is not resolvable. **Censoring**: a cell with more than a "
        "quarter of its episodes at the step cap is a lower bound (`≥`); a ratio over a capped cell cannot "
        "reproduce, one of a capped cell cannot contradict. **Fails**, one definition for every claim: did not "
        "learn by the gate — the survival interval not above "
        f"{inp.verdict_rules.fails_factor:g}× the better of random and stand-still on that level. **The gate "
        "decides nothing**: every agent is compared; a part the data leave undecided says which of its agents "
        'did not learn. (d)\'s "no monotonic gain": the gain of mean testbed success along the least-squares '
        "line from the first training level to the last, its 95 % interval from a two-stage bootstrap that redraws "
        "a curriculum's seeds together across its levels — at or under "
        f"+{inp.verdict_rules.gain_margin:g} (no gain beyond the margin) reproduces, above it contradicts — or a "
        "drop between consecutive training levels (one-sided two-proportion tests on the effective episodes, "
        "Holm-corrected over the steps), which reproduces too; the power of both at these seeds and episodes is "
        f"stated ({100 * inp.verdict_rules.power:.0f} %). A part whose agent cells have fewer than {MIN_SEEDS} "
        "seeds has no interval and is not decided (`not resolvable: 2 seeds`); agents that acted differently are "
        "not compared"
        + (
            f" — the claims compare the checkpoints acting {inp.compared}, and the other acting modes' numbers "
            "in the tables decide nothing"
            if inp.compared
            else ""
        )
        + ". (b) compares at matched total env steps where direct runs of a "
        "curriculum stage's total exist, else at equal env steps per stage (the curriculum stage has seen "
        "more). A claim of several parts is reproduced when every part is, contradicted when any part is (it "
        "states each of them), otherwise not resolvable. Survival per level: "
        + source_words(inp)
        + " (runs with every sense; curriculum runs where an "
        "algorithm has them). Testbed success: each run's furthest-trained evaluated checkpoint" + how + ".",
        "",
    ]
    if inp.learned_factor is not None:
        gate = inp.gate
        level = evaaa.LEVELS[0]
        known = set(gate["algo"])
        unknown = sorted({r.algo for r in inp.usable} - known)
        doc.md += [
            f"**Which agents learned.** An agent learned {level} when the 95 % interval of its network with every "
            f"sense (IQM of its seeds' episodes) lies above {inp.learned_factor:g}× the better of random and "
            "stand-still there, judged at the budget it is compared at: its compute-matched runs for the comparison "
            f"at equal compute; for the others its direct runs on {level} with a step budget, else its "
            'curriculum\'s first stage. One whose interval does not "did not learn at this budget" — the one '
            'meaning of "fails" in the claims. The gate decides no part: it explains parts the data leave '
            "undecided.",
            "",
            *[f"- {r}" for r in gate["reading"]],
            *[f"- {a}: no evaluation of its network with every sense on {level}" for a in unknown],
            "",
        ]
    doc.md += rules.markdown(inp.verdicts)
    doc.md.append("")
