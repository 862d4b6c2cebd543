"""A training run from a composed config: its stages (one level, or the curriculum's levels in order), a fresh start
or the resume of a killed run, and the logger the stages share.

``scripts/train.py`` calls :func:`train` with Hydra's run directory; tests call it with a config from Hydra's
compose API.

A run directory is an append-only record of one run.  Every check is made before anything in it is written (the
config files included: ``scripts/train.py`` has Hydra leave ``.hydra/`` to :func:`train`), so a refused command
leaves every file of the existing run as it was:

- a directory holding a checkpoint needs ``resume=true`` (continue exactly) or ``start_over=true``;
- ``resume=true`` continues from ``checkpoint.pt``, or from ``checkpoint-previous.pt`` when the latest is damaged;
  with no checkpoint it starts from zero, saying so, if the directory holds no results, or moves the results of a
  run that never reached its first checkpoint aside; it refuses where a finished run's checkpoint is gone;
- ``start_over=true`` moves an existing run aside (a hidden sibling folder, named in the log) and starts from zero.

Ctrl-C: the first one lets the gradient step (DreamerV3) or iteration (the others) under way finish, writes a
checkpoint and stops (:class:`~baselines.run.Interrupted`, one line); a second one stops within seconds, even
inside a minute-long gradient step (:class:`StopRequest`).  SIGTERM and SIGUSR2 (:data:`STOP_SIGNALS`: ``kill``,
``scancel``, a SLURM time limit or pre-emption through submitit) stop the run as the first Ctrl-C does.
"""

from __future__ import annotations

import csv
import logging
import os
import shlex
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from torchrl.record.loggers import Logger, get_logger

from .algos import algorithm
from .checkpoint import CHECKPOINT, PREVIOUS, CheckpointError, load_latest, remove_stale_temporaries, seed_everything
from .config import observation_keys, stages
from .devices import deterministic_kernels, resolve_device
from .machine import keep_freed_memory
from .paths import CONF_DIR
from .run import Interrupted, Run

log = logging.getLogger(__name__)


def make_logger(cfg: DictConfig, run_dir: Path, state: dict | None) -> Logger:
    """TorchRL's logger of ``cfg.logger.backend`` writing under ``run_dir`` (``state``: continue a checkpointed one)."""
    backend = cfg.logger.backend
    if backend == "wandb":
        kwargs = {"wandb_kwargs": {"offline": cfg.logger.offline, "project": cfg.logger.project}}
        name = cfg.run.name  # a W&B run name; its files go to <run_dir>/wandb
    else:
        kwargs, name = {}, "logs"  # a sub-directory of the run directory
    return get_logger(backend, str(run_dir), name, state_dict=state, **kwargs)


def flat_hparams(cfg: DictConfig) -> dict[str, int | float | str | bool]:
    """The config as ``{"algo.lr": 0.0001, ...}`` with scalar values, as every logger's ``log_hparams`` accepts."""
    flat: dict[str, int | float | str | bool] = {}

    def visit(node, prefix: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                visit(value, f"{prefix}{key}.")
        else:
            flat[prefix[:-1]] = node if isinstance(node, (int, float, str, bool)) else str(node)

    visit(OmegaConf.to_container(cfg, resolve=True), "")
    return flat


class RunRefused(Exception):
    """The command would change an existing run's files: nothing was written."""


class RunExists(RunRefused, FileExistsError):
    """The run directory already holds a run that this command may not continue."""


class OtherExperiment(RunRefused, ValueError):
    """The checkpoint to resume was made by a different experiment."""


def _check_same_run(state: dict, cfg: DictConfig, plan: list) -> list[str]:
    """Refuse to resume a checkpoint of a different experiment; returns the settings that changed."""
    saved = state["config"]
    expected = {
        "algo": (state["algo"], cfg.algo.name),
        "observation keys": (list(state["obs_keys"]), list(observation_keys(cfg))),
        "levels": ([s["level"] for s in saved["stages"]], [s.level for s in plan]),
        "seed": (saved["seed"], cfg.seed),
        "env.num_envs": (state["num_envs"], cfg.env.num_envs),
    }
    wrong = {k: v for k, v in expected.items() if v[0] != v[1]}
    if wrong:
        detail = "; ".join(f"{k}: checkpoint {a}, now {b}" for k, (a, b) in wrong.items())
        raise OtherExperiment(
            f"cannot resume: the checkpoint belongs to another experiment ({detail}); nothing was changed"
        )
    now, before = flat_hparams(cfg), flat_hparams(OmegaConf.create(saved))
    return sorted(
        k
        for k in now.keys() | before.keys()
        if k not in ("resume", "start_over") and not k.startswith("stages") and now.get(k) != before.get(k)
    )


# ------------------------------------------------------------------------------------------------ run directory
#: what Hydra or this module write before training: not results of a run
_BOOKKEEPING = (".hydra",)


def run_contents(run_dir: Path) -> list[str]:
    """Names of what ``run_dir`` holds beyond bookkeeping (Hydra's ``.hydra/`` and job logs, temporary files of a
    killed write, training CSVs holding only their header): the results of a run."""
    if not run_dir.is_dir():
        return []
    found = []
    for entry in sorted(run_dir.iterdir()):
        name = entry.name
        if name in _BOOKKEEPING or name.endswith(".log") or name.endswith(".tmp"):
            continue
        if name in ("episodes.csv", "eval.csv") and entry.is_file():
            with open(entry, "rb") as f:
                if len(f.read(1 << 16).splitlines()) <= 1:  # at most a header
                    continue
        found.append(name)
    return found


def _aside(run_dir: Path) -> Path:
    """A new hidden sibling of ``run_dir`` (reports skip hidden folders) to move an old run to."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for n in range(1000):
        target = run_dir.with_name(f".{run_dir.name}.replaced-{stamp}" + (f"-{n}" if n else ""))
        if not target.exists():
            return target
    raise RunExists(f"{run_dir}: no free name to move the old run to")


#: what a refusal of an occupied run folder offers instead
START_OVER = (
    "start_over=true moves it aside (to a hidden folder beside it, which reports skip) and trains from "
    "zero; or choose another run.name / run.root"
)
#: what :func:`_decide` returns: the checkpoint state to resume (or None), the lines to log, where to move an old run
Decision = tuple[dict | None, list[tuple[int, str]], Path | None]


def _decide(cfg: DictConfig, run_dir: Path, plan: list) -> Decision:
    """What to do with ``run_dir``, decided before anything is written: the checkpoint state to resume (or None),
    the lines to log (level, message) once the run goes ahead, and where an old run is to be moved first (or None).

    Raises :class:`RunRefused` or :class:`~baselines.checkpoint.CheckpointError` when the command may not go on."""
    if cfg.get("start_over") and cfg.resume:
        raise RunRefused("resume=true and start_over=true contradict each other: choose one")
    contents = run_contents(run_dir)
    has_checkpoint = any(name in contents for name in (CHECKPOINT, PREVIOUS))
    if cfg.get("start_over"):
        return _start_over(run_dir, contents)
    if not cfg.resume:
        if has_checkpoint:
            raise RunExists(
                f"{run_dir} already holds a run (checkpoint.pt); nothing was changed. resume=true "
                f"continues it; {START_OVER}"
            )
        if contents:
            raise RunExists(
                f"{run_dir} already holds a run's results ({', '.join(contents)}); nothing was changed. {START_OVER}"
            )
        return None, [], None
    if has_checkpoint:
        return _resume(cfg, run_dir, plan)
    return _resume_without_checkpoint(run_dir, contents)


def _start_over(run_dir: Path, contents: list[str]) -> Decision:
    """``start_over=true``: the run there (if any) moved aside, training from zero."""
    if not contents:
        return None, [(logging.INFO, f"start_over=true: {run_dir} holds no run; starting from zero")], None
    target = _aside(run_dir)
    message = (
        f"start_over=true: the run that was in {run_dir} ({', '.join(contents)}) is now in {target}; starting from zero"
    )
    return None, [(logging.WARNING, message)], target


def _resume(cfg: DictConfig, run_dir: Path, plan: list) -> Decision:
    """``resume=true`` where a checkpoint is: its state, checked to be this command's run."""
    try:
        found = load_latest(run_dir)
    except CheckpointError as err:
        raise CheckpointError(f"cannot resume {run_dir}: {err}; nothing was changed. {START_OVER}") from None
    assert found is not None
    state, path, note = found
    try:
        changed = _check_same_run(state, cfg, plan)
        notes = [(logging.WARNING, note)] if note else []  # a damaged latest checkpoint: said once the run goes on
        # "resuming ... env step <digits>": scripts/bench_train.py finds a run's sessions by it in train.log
        notes.append(
            (
                logging.INFO,
                f"resuming {run_dir} from {path.name} at stage {state['stage']} "
                f"({state['level']}), env step {state['counters']['steps']}",
            )
        )
    except (KeyError, TypeError, AttributeError, IndexError) as err:  # a crafted file, its checksum valid
        raise CheckpointError(
            f"cannot resume {run_dir}: {path} is malformed: its record of the run is incomplete "
            f"({type(err).__name__}: {' '.join(str(err).split())[:200]}); nothing was changed. {START_OVER}"
        ) from None
    if changed:
        notes.append((logging.WARNING, "resuming with changed settings in: " + ", ".join(changed)))
    return state, notes, None


def _resume_without_checkpoint(run_dir: Path, contents: list[str]) -> Decision:
    """``resume=true`` where no checkpoint is: from zero, unless a finished run's results are there."""
    if not contents:
        return None, [(logging.WARNING, f"resume=true: {run_dir} holds no checkpoint yet: starting from zero")], None
    if any(name.startswith("model-") for name in contents):
        raise RunExists(
            f"cannot resume {run_dir}: it holds a trained run's results ({', '.join(contents)}) but "
            f"no checkpoint (checkpoint.pt was deleted or lost); nothing was changed. {START_OVER}"
        )
    # a run stopped before its first checkpoint: nothing to continue, and nothing finished to keep in place
    target = _aside(run_dir)
    message = (
        f"resume=true: {run_dir} stopped before its first checkpoint, so it starts from zero; what it had written "
        f"({', '.join(contents)}) is now in {target}"
    )
    return None, [(logging.WARNING, message)], target


def _write_records(run_dir: Path, records: Mapping[str, Any] | None, resumed: bool) -> None:
    """Hydra's record of the command (``.hydra/config.yaml``, ``hydra.yaml``, ``overrides.yaml``), once the run goes
    ahead; a resumed run keeps the files of its earlier sessions as ``<name>.session-<n>.yaml`` when they differ."""
    if not records:
        return
    folder = run_dir / ".hydra"
    folder.mkdir(exist_ok=True)
    for name, content in records.items():
        path = folder / name
        text = OmegaConf.to_yaml(content if OmegaConf.is_config(content) else OmegaConf.create(content))
        if path.exists():
            old = path.read_text()
            if old == text:
                continue
            if resumed:
                n = 1
                while (kept := path.with_name(f"{path.stem}.session-{n}.yaml")).exists():
                    n += 1
                path.rename(kept)
        path.write_text(text)


#: the signals that ask a training to stop at its next safe point with a checkpoint: Ctrl-C (SIGINT), SIGTERM (``kill``,
#: ``scancel``, a node shutting down) and SIGUSR2 (what submitit has SLURM send ahead of a job's time limit, and on
#: pre-emption; ``scripts/train.py`` then lets submitit requeue the job)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGUSR2)


class StopRequest:
    """Ctrl-C while a run trains.  The first SIGINT asks the loop to stop at its next safe point (after the gradient
    step under way for DreamerV3, after the iteration for the others), where it writes a checkpoint; a second one
    stops at once.  SIGTERM and SIGUSR2 ask what the first Ctrl-C asks, however many arrive (a scheduler's signals
    never turn the checkpointed stop into one without a checkpoint; its SIGKILL ends what does not stop in time);
    :attr:`signals` keeps which arrived, in order.

    Python runs a signal handler only between bytecodes, and signals that arrive while the main thread is inside
    one long call (a DreamerV3-S backward pass on a CPU: a minute) reach the handler as ONE call.  So the signals
    are also counted by a watcher thread that reads the wakeup fd (``signal.set_wakeup_fd``: one byte per signal,
    written by the C-level handler as it arrives): it says at once what the first Ctrl-C waits for, and after a
    second one it gives the main thread :attr:`GRACE` seconds to stop by ``KeyboardInterrupt`` before ending the
    process itself (``os._exit``: the last checkpoint is complete on disk, a half-written one is a ``.tmp`` that the
    next start removes)."""

    #: seconds a second Ctrl-C waits for the main thread before the process is ended from the watcher thread
    GRACE = 3.0

    def __init__(self, run_dir: Path):
        self.run_dir = run_dir
        self.event = threading.Event()
        self.finished = threading.Event()
        #: what the first Ctrl-C waits for, in words (the stage under way sets it: :meth:`Run.stop_wait`)
        self.wait: Callable[[], str] = lambda: "the iteration under way"
        self._handled = 0  # SIGINTs the Python handler has seen (two coalesced signals count once here)
        #: the stop signals that arrived (each once, in order of arrival)
        self.signals: list[int] = []

    def is_set(self) -> bool:
        return self.event.is_set()

    def request(self, signum: int = signal.SIGINT) -> None:
        if signum not in self.signals:
            self.signals.append(signum)
        if not self.event.is_set():
            self.event.set()
            what = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
            again = "Ctrl-C again" if signum == signal.SIGINT else "Ctrl-C twice"
            log.warning(
                "%s: stopping after %s, then writing a checkpoint (%s to stop at once)", what, self.wait(), again
            )

    def handler(self, signum, frame) -> None:
        if signum == signal.SIGINT:
            self._handled += 1
            if self._handled >= 2:
                raise KeyboardInterrupt
        self.request(signum)

    def watch(self, fd: int) -> None:
        """The watcher thread: one byte per signal on ``fd``; 0 ends it."""
        signals = 0
        while True:
            try:
                data = os.read(fd, 64)
            except InterruptedError:
                continue
            if not data or 0 in data:
                return
            for signum in data:
                if signum in STOP_SIGNALS:
                    self.request(signum)
            signals += data.count(signal.SIGINT)
            if signals >= 2:
                if self.finished.wait(self.GRACE):
                    return
                print(f"{Path(sys.argv[0]).name}: {stopped_at_once(self.run_dir)}", file=sys.stderr, flush=True)
                os._exit(130)


def stopped_at_once(run_dir: Path) -> str:
    """What a second Ctrl-C leaves: the checkpoint a resume continues from, or none."""
    latest = run_dir / CHECKPOINT
    if latest.exists():
        return f"stopped at once: no new checkpoint; the same command with resume=true continues from the last one, {latest}"
    return (
        f"stopped at once, before the first checkpoint: there is no checkpoint to continue from; the same command "
        f"with start_over=true starts {run_dir} again from zero"
    )


@contextmanager
def _graceful_interrupts(run_dir: Path) -> Iterator[StopRequest]:
    """Ctrl-C, SIGTERM and SIGUSR2 as :class:`StopRequest` says while the block runs; the handlers before it are put
    back after it.  Outside the main thread, the signals keep their usual meaning."""
    stop = StopRequest(run_dir)
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {signum: signal.signal(signum, stop.handler) for signum in STOP_SIGNALS}
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    try:
        old_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    except ValueError:  # not the main interpreter: the handler alone counts
        old_fd = None
    watcher = None
    if old_fd == -1:
        watcher = threading.Thread(target=stop.watch, args=(read_fd,), name="ctrl-c", daemon=True)
        watcher.start()
    elif old_fd is not None:
        signal.set_wakeup_fd(old_fd)  # someone else's (an event loop): leave it to them
    try:
        yield stop
    finally:
        stop.finished.set()
        if watcher is not None:
            signal.set_wakeup_fd(-1)
            os.write(write_fd, b"\0")
            watcher.join()
        os.close(read_fd)
        os.close(write_fd)
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def train(cfg: DictConfig, run_dir: str | Path, *, records: Mapping[str, Any] | None = None) -> Path:
    """Train the configured algorithm on the configured level(s) in ``run_dir``; returns the run directory.

    Writes ``checkpoint.pt`` (latest state, every ``checkpoint.every`` env steps, at the end of each stage and on
    Ctrl-C) beside ``checkpoint-previous.pt``, ``model-<stage>-<level>.pt`` (the weights at the end of each stage),
    ``episodes.csv``, ``eval.csv``, the logger's files and ``records`` (Hydra's config files, under ``.hydra/``).
    With ``resume=true`` a run with a checkpoint continues exactly where that checkpoint was taken.

    Raises :class:`RunRefused` (or ``CheckpointError``) before writing anything when the command would change an
    existing run (see the module docstring), and :class:`~baselines.run.Interrupted` on Ctrl-C, SIGTERM or SIGUSR2
    (its ``signals``: the ones that arrived).
    """
    run_dir = Path(run_dir)
    # from the start: a Ctrl-C while the checks run or an old run is moved aside waits for a consistent state too
    with _graceful_interrupts(run_dir) as stop:
        try:
            return _train(cfg, run_dir, records, stop)
        except KeyboardInterrupt as err:
            stopped = err if isinstance(err, Interrupted) else Interrupted(stopped_at_once(run_dir))
            stopped.signals = tuple(stop.signals)
            raise stopped from None


def _train(cfg: DictConfig, run_dir: Path, records: Mapping[str, Any] | None, stop: StopRequest) -> Path:
    device = resolve_device(cfg.get("device", "auto"))  # a device this machine lacks fails here, before any write
    deterministic_kernels(cfg.get("deterministic", True), device)
    algo = algorithm(cfg.algo.name)
    plan = stages(cfg)
    state, notes, aside = _decide(cfg, run_dir, plan)

    # from here on the run goes ahead: the directory may change
    if aside is not None:
        run_dir.rename(aside)  # the name the notes below give
    run_dir.mkdir(parents=True, exist_ok=True)
    for tmp in remove_stale_temporaries(run_dir):
        notes.append((logging.INFO, f"removed {tmp}, left by a process killed while writing it"))
    for level, note in notes:
        log.log(level, note)
    _write_records(run_dir, records, resumed=state is not None)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    keep_freed_memory()  # the loop's large tensors reused, not page-faulted in afresh each iteration
    if state is None:
        seed_everything(cfg.seed)

    # the stage plan goes into the saved config, so a resume can check it trains the same levels in the same order
    cfg = cfg.copy()
    OmegaConf.set_struct(cfg, False)
    cfg.stages = [{"level": s.level, "budget": s.budget} for s in plan]

    logger = make_logger(cfg, run_dir, state["logs"]["logger"] if state else None)
    try:
        if state is None:
            logger.log_hparams(flat_hparams(cfg))
        weights = None
        for stage in plan[state["stage"] if state else 0 :]:
            run = Run(
                cfg,
                run_dir,
                stage,
                logger,
                resume=state,
                init_weights=weights,
                fresh_logs=state is None and stage.index == 0,
                stop_requested=stop.is_set,
            )
            stop.wait = run.stop_wait
            try:
                algo.train(run)
            finally:
                _quietly(run.close)
            weights = run.model.state_dict()
            state = None
    finally:
        _quietly(logger.shutdown)
    return run_dir


def _eval_rows(run_dir: Path) -> list[dict]:
    """The rows of the run's ``eval.csv`` (none where it has no evaluation)."""
    if not (run_dir / "eval.csv").is_file():
        return []
    with open(run_dir / "eval.csv", newline="") as f:
        return list(csv.DictReader(f))


#: the reference agents a finished run's final evaluation is shown beside, as the summary names them
BESIDE = {"random": "random", "still": "stand-still"}


def reference_survival(cfg: DictConfig, run_dir: Path) -> dict[str, float]:
    """Mean survival of the random and stand-still agents on the worlds of the run's final evaluation — its level,
    its ``eval.episodes`` validation worlds of the run's seed, the run's level settings — so that the summary
    shows what the network's number is worth (standing still outlives many a policy on 1-1).  A progress bar
    counts their episodes where the output is a terminal.  Empty where the run made no evaluation."""
    from tqdm import tqdm

    import evaaa
    from evaaa.agents import RandomAgent, StillAgent

    from .config import env_overrides
    from .rollout import EVALUATION_INFO, evaluate

    rows = _eval_rows(Path(run_dir))
    if not rows:
        return {}
    level, n = rows[-1]["level"], int(cfg.eval.episodes)
    survival = {}
    shown = bool(OmegaConf.select(cfg, "progress", default=True))
    with tqdm(
        total=len(BESIDE) * n,
        desc=f"{' and '.join(BESIDE.values())} on the same worlds",
        unit="episode",
        dynamic_ncols=True,
        leave=False,
        disable=None if shown else True,
    ) as bar:
        for name in BESIDE:
            agent = RandomAgent(int(cfg.seed)) if name == "random" else StillAgent()
            # the final evaluation's env (Run.evaluate) without the senses these agents do not read
            env = evaaa.make_env(
                level,
                num_envs=n,
                modalities=["interoception"],
                info=EVALUATION_INFO,
                worlds="validation",
                **env_overrides(cfg),
            )
            try:
                env.set_seed(int(cfg.seed), static_seed=True)

                def act(td, env=env, agent=agent):
                    return td.set("action", torch.from_numpy(agent.act(env.sim)).reshape(td.batch_size))

                survival[name] = evaluate(env, act, on_episode=bar.update).survival_mean
            finally:
                env.close()
    return survival


def summary(cfg: DictConfig, run_dir: Path, beside: Mapping[str, float] | None = None) -> str:
    """What a finished run shows last: its folder, its final evaluation (the last rows of ``eval.csv``) with
    ``beside`` (:func:`reference_survival`: random's and stand-still's mean survival on the same worlds), and its
    final model."""
    run_dir = Path(run_dir)
    with suppress(ValueError):  # as the command named it: runs/..., not the absolute path Hydra resolved
        run_dir = run_dir.resolve().relative_to(Path.cwd().resolve())
    rows = _eval_rows(run_dir)
    lines = [f"run folder: {run_dir}"]
    if rows:
        last = rows[-1]
        # the last evaluation: its episodes (one row each, on the run's validation worlds)
        final = [r for r in rows if (r["env_steps"], r["stage"]) == (last["env_steps"], last["stage"])]
        steps = [int(r["steps"]) for r in final]
        ends = ", ".join(f"{name} {n}" for name, n in Counter(r["end_type"] for r in final).most_common())
        acting = (
            "actions sampled from the policy"
            if last.get("acting", "").startswith("sample")
            else "the policy's most likely actions"
        )
        lines.append(
            f"final evaluation on {last['level']} at env step {int(last['env_steps']):,} ({last['worlds']} "
            f"worlds): mean survival {sum(steps) / len(steps):.0f} steps over {len(steps)} episodes (min "
            f"{min(steps)}, max {max(steps)}; {acting}; ended by {ends})"
        )
        if beside:
            lines.append(
                "on the same worlds: "
                + ", ".join(f"{BESIDE.get(name, name)} {value:.0f}" for name, value in beside.items())
                + " steps (mean survival)"
            )
        model = run_dir / f"model-{last['stage']}-{last['level']}.pt"
        if model.exists():
            # absolute paths: the command works from any folder; a level of your own is named by its file
            file = OmegaConf.select(cfg, "level.file", default=None)
            own = isinstance(file, str) and last["level"] == Path(file).stem
            level = Path(file).resolve() if own else last["level"]
            command = [
                "python",
                str(CONF_DIR.parent / "scripts" / "evaluate.py"),
                f"policy={model.resolve()}",
                f"levels=[{level}]",
            ]
            lines.append(f"final model: {model} ({shlex.join(command)} evaluates it on the test worlds)")
    else:
        lines.append("no evaluation was made (eval.every=0)")
    return "\n".join(lines)


def _quietly(cleanup) -> None:
    """Run a clean-up step; while an error or interrupt is on its way out, a failing clean-up must not replace it."""
    if sys.exc_info()[1] is None:
        cleanup()
        return
    with suppress(Exception):
        cleanup()
